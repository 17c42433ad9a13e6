import json

import pytest

from riskplan.app.store import ResultStore, canonical_json, fingerprint
from riskplan.errors import DataFormatError, InvalidInputError

CFG = {"paper": "deformable", "scale": "smoke", "seed": 0}


def test_round_trip_and_resume(tmp_path):
    store = ResultStore(tmp_path, CFG)
    calls = []

    def compute():
        calls.append(1)
        return {"hits": 3, "n": 10, "rates": [0.1, 0.2]}

    first = store.get_or_compute("needle_ours_mesh_0", compute)
    again = ResultStore(tmp_path, dict(CFG)).get_or_compute("needle_ours_mesh_0", compute)
    assert first == again == {"hits": 3, "n": 10, "rates": [0.1, 0.2]}
    assert len(calls) == 1
    assert store.keys() == ["needle_ours_mesh_0"]
    assert "needle_ours_mesh_0" in store and "other" not in store


def test_corrupted_record_is_named(tmp_path):
    store = ResultStore(tmp_path, CFG)
    store.put("batch_1", {"hits": 3})
    path = tmp_path / "records" / "batch_1.json"
    rec = json.loads(path.read_text())
    rec["payload"]["hits"] = 4  # edited behind the store's back
    path.write_text(json.dumps(rec))
    with pytest.raises(DataFormatError, match=r"batch_1.json.*hash"):
        store.get("batch_1")
    path.write_text(path.read_text()[:20])  # truncated
    with pytest.raises(DataFormatError, match=r"batch_1.json"):
        store.get("batch_1")


def test_other_configuration_is_refused(tmp_path):
    ResultStore(tmp_path, CFG).put("a", 1)
    with pytest.raises(DataFormatError, match="another run configuration"):
        ResultStore(tmp_path, {**CFG, "seed": 1})
    # a record copied in from another run's store is refused too
    other = ResultStore(tmp_path / "other", {**CFG, "seed": 1})
    other.put("b", 2)
    (tmp_path / "records" / "b.json").write_text(
        (tmp_path / "other" / "records" / "b.json").read_text()
    )
    with pytest.raises(DataFormatError, match="another run configuration"):
        ResultStore(tmp_path, CFG).get("b")


def test_bad_keys_and_payloads(tmp_path):
    store = ResultStore(tmp_path, CFG)
    for key in ("", "../x", "a/b", 3):
        with pytest.raises(InvalidInputError, match="key"):
            store.put(key, 1)
    with pytest.raises(InvalidInputError, match="payload"):
        store.put("nan", float("nan"))
    assert store.keys() == []


def test_canonical_json_and_fingerprint_are_order_free():
    assert canonical_json({"b": 1, "a": [1, 2]}) == '{"a":[1,2],"b":1}'
    assert (
        fingerprint({"a": 1, "b": 2})
        == fingerprint({"b": 2, "a": 1})
        != fingerprint({"a": 1, "b": 3})
    )
