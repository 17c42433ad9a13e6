"""Shared Hypothesis strategies and checks for the property-based tests of every public area.

Contract checked everywhere: an entry point given arbitrary floats, shapes and types either
raises a :class:`~riskplan.errors.RiskplanError` subclass or returns a finite, in-range result;
never another exception, never NaN.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from riskplan.errors import RiskplanError

# modest and deterministic: the six modules together stay well under a minute on 2 cores
PROPERTY = settings(
    max_examples=30,
    deadline=None,
    derandomize=True,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.function_scoped_fixture,
        HealthCheck.data_too_large,
    ],
)

any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)
finite_float = st.floats(allow_nan=False, allow_infinity=False, width=64)
small_shapes = hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=4)


def float_arrays(shape=small_shapes, elements=any_float):
    return hnp.arrays(np.float64, shape, elements=elements)


def junk():
    """Values of the wrong type: None, strings, booleans, complex numbers, nested lists, dicts."""
    return st.one_of(
        st.none(),
        st.text(max_size=8),
        st.booleans(),
        st.complex_numbers(allow_nan=True, allow_infinity=True),
        st.lists(st.one_of(st.text(max_size=3), any_float), max_size=4),
        st.dictionaries(st.text(max_size=3), any_float, max_size=2),
    )


def arrays_or_junk(shape=small_shapes, elements=any_float):
    return st.one_of(float_arrays(shape, elements), junk(), any_float)


def call(fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, or ``None`` if it raised a RiskplanError (any other exception propagates)."""
    try:
        return fn(*args, **kwargs)
    except RiskplanError:
        return None


def assert_finite(*arrays) -> None:
    for a in arrays:
        a = np.asarray(a)
        assert a.dtype.kind in "biuf", a.dtype
        assert np.all(np.isfinite(a)), a


def assert_probability(p) -> None:
    p = np.asarray(p, dtype=np.float64)
    assert np.all(np.isfinite(p)) and np.all((p >= 0.0) & (p <= 1.0)), p


@pytest.fixture(autouse=True, scope="module")
def small_budget():
    """Arbitrary sizes must meet the work budget, not the machine's memory: a 32 MiB ceiling
    for the property tests of a module (a request just under the default would allocate
    gigabytes in a test)."""
    from riskplan.budget import MEMORY_ENV

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(MEMORY_ENV, "32M")
        yield
