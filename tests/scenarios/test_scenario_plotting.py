"""Frames and GIFs of both scenarios (files written, frame counts, index selection)."""

from __future__ import annotations

import numpy as np
from PIL import Image

from riskplan.scenarios.base import rollout
from riskplan.scenarios.plotting import frame_indices, save_frames, save_gif


def test_frame_indices():
    assert frame_indices(5, 10) == [0, 1, 2, 3, 4]
    idx = frame_indices(101, 7)
    assert idx[0] == 0 and idx[-1] == 100 and len(idx) == 7


def test_needle_gif_and_frames(needle, tmp_path):
    states = rollout(needle, needle.initial_state(), needle.random_controls(6, 0))
    gif = save_gif(needle, states, tmp_path / "n.gif", max_frames=4)
    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames == 4
    frames = save_frames(needle, states, tmp_path / "f", max_frames=3)
    assert [p.name for p in frames] == ["frame_0000.png", "frame_0003.png", "frame_0006.png"]
    assert not list(tmp_path.glob(".n.gif*"))  # no temporary file left behind


def test_manipulation_frames(manip, tmp_path):
    states = rollout(manip, manip.initial_state(), np.tile([0.3, 0.3, 0.0, 0.3, -0.3, 0.3], (2, 1)))
    frames = save_frames(manip, states, tmp_path, max_frames=3)
    assert len(frames) == 3
    with Image.open(frames[-1]) as im:
        arr = np.asarray(im.convert("RGB"))
    # something red (manipulators) and blue (target) was drawn
    assert np.any((arr[..., 0] > 180) & (arr[..., 1] < 80) & (arr[..., 2] < 80))
    assert np.any((arr[..., 2] > 150) & (arr[..., 0] < 80))
