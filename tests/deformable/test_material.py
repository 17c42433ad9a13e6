"""Material parameters: validation at the boundary."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.deformable.material import Material
from riskplan.errors import InvalidInputError


@pytest.mark.parametrize(
    "args, match",
    [
        (("50", 0.4), "E: expected a real number"),  # used to be accepted as 50.0
        ((50.0, "0.4"), "nu: expected a real number"),
        ((True, 0.4), "E: expected a real number"),
        ((1e308, 0.4), "<= 1e\\+30"),  # used to overflow later, inside the solver
        ((np.inf, 0.4), "finite"),
        ((-1.0, 0.4), "> 0"),
        ((50.0, 0.5), "Poisson"),
        ((None, 0.4), "real number"),
    ],
)
def test_bad_materials_are_named_errors(args, match):
    with pytest.raises(InvalidInputError, match=match):
        Material(*args)


def test_numpy_scalars_accepted():
    m = Material(np.float64(50.0), np.float32(0.4))
    assert isinstance(m.E, float) and m.E == 50.0
