"""Fixtures of the command tests that other trees define: the kinematics commands train and
predict on the synthetic data sets of ``tests/kinematics`` (their known mixture is the oracle)."""

from tests.kinematics.conftest import synth_paths, synth_small, trained  # noqa: F401
