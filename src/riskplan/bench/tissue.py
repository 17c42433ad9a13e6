"""Speed of one tissue-simulator step, timed through the scenarios' public ``step``:
``riskplan bench tissue --json`` and ``riskplan tissue step-cost``.

One *step* is what a planner's simulator does per control: ``Scenario.step`` (the
quasi-static response to the new load, warm-started from the given state) and then the
deformed geometry read off the new state. Medians over repeated calls from one state
with one control, warm caches (mesh, FEM model and compiled kernels built before timing),
nominal parameters, meshes of 175 elements (the planning mesh) and 1000 elements:

* needle (V-A, linear elasticity): :meth:`NeedleScenario.step` at the pose
  ``(0.3, 0.45, 0.2)`` with ``u = (0.5, 0.3)``, alone (``needle_step_us_N``) and followed by
  :meth:`NeedleScenario.in_collision`, which reads the deformed obstacles' material points
  (``needle_step_and_collision_us_N``; :func:`linear_step_ms`);
* manipulation (V-B, neo-Hookean): :meth:`ManipulationScenario.step` from the equilibrium
  under forces 0.5 (reached in two increments of 0.25) by a small force increment
  (warm-started Newton; ``manipulation_step_ms_N``) and :meth:`ManipulationScenario.reduced`,
  the target, boundary points and forces (``manipulation_reduced_us_N``); step and
  ``reduced`` together: :func:`nonlinear_step_ms`.

:func:`run` (``riskplan bench tissue``) reports ``linear_step_ms_N`` and
``nonlinear_step_ms_N``, the step plus reading the points; :func:`step_costs` (``riskplan
tissue step-cost``) the parts, in µs or ms as the key says.
"""

from __future__ import annotations

import numpy as np

from riskplan.bench import median_time

#: Element counts timed: the planning mesh and a fine one.
ELEMENTS = (175, 1000)


def needle_setup(n_elements: int):
    """``(scenario, params, state, control)`` of the needle step timed here (module docstring)."""
    from riskplan.scenarios.base import SimParams
    from riskplan.scenarios.needle import NeedleScenario

    sim = NeedleScenario()
    params = SimParams(n_elements=n_elements)
    state = sim.initial_state(params, pose=(0.3, 0.45, 0.2))
    return sim, params, state, np.array([0.5, 0.3])


def manipulation_setup(n_elements: int):
    """``(scenario, params, state, control)`` of the manipulation step timed here: the state
    is the equilibrium under forces 0.5, the control a small increment of them."""
    from riskplan.scenarios.base import SimParams
    from riskplan.scenarios.manipulation import ManipulationScenario

    sim = ManipulationScenario()
    params = SimParams(n_elements=n_elements)
    state = sim.initial_state(params)
    for _ in range(2):
        state = sim.step(state, np.full(6, 0.25), params)
    control = 0.05 * np.array([1.0, -1.0, 0.5, 0.2, -0.3, 0.1])
    return sim, params, state, control


def _step_and_collision(sim, p, s, u):
    return lambda: sim.in_collision(sim.step(s, u, p))


def _step_and_reduced(sim, p, s, u):
    return lambda: sim.reduced(sim.step(s, u, p))


def linear_step_ms(n_elements: int, repeats: int = 200) -> float:
    """Median milliseconds of a needle step plus its collision check (module docstring)."""
    return 1e3 * median_time(_step_and_collision(*needle_setup(n_elements)), repeats, warmup=20)


def nonlinear_step_ms(n_elements: int, repeats: int = 30) -> float:
    """Median milliseconds of a manipulation step plus ``reduced`` (module docstring)."""
    return 1e3 * median_time(_step_and_reduced(*manipulation_setup(n_elements)), repeats, warmup=2)


def _needle_costs(n: int, reps: int) -> dict:
    sim, p, s, u = setup = needle_setup(n)
    step_s = median_time(lambda: sim.step(s, u, p), repeats=reps, warmup=20)
    both_s = median_time(_step_and_collision(*setup), repeats=reps, warmup=20)
    return {
        f"needle_step_us_{n}": round(1e6 * step_s, 1),
        f"needle_step_and_collision_us_{n}": round(1e6 * both_s, 1),
    }


def _manipulation_costs(n: int, reps: int, step_reps: int) -> dict:
    sim, p, s, u = manipulation_setup(n)
    step_s = median_time(lambda: sim.step(s, u, p), repeats=step_reps, warmup=2)
    reduced_s = median_time(lambda: sim.reduced(s), repeats=reps, warmup=10)
    return {
        f"manipulation_step_ms_{n}": round(1e3 * step_s, 2),
        f"manipulation_reduced_us_{n}": round(1e6 * reduced_s, 1),
    }


def step_costs(quick: bool = False) -> dict:
    """The parts of a step (module docstring): ``needle_step_us_N``,
    ``needle_step_and_collision_us_N``, ``manipulation_step_ms_N``,
    ``manipulation_reduced_us_N`` for ``N`` in :data:`ELEMENTS`."""
    reps = 200 if quick else 2000
    out = {}
    for n in ELEMENTS:
        out.update(_needle_costs(n, reps))
    for n in ELEMENTS:
        out.update(_manipulation_costs(n, reps, 10 if quick else 40))
    return out


def run(quick: bool = False) -> dict:
    """``{"linear_step_ms_175", "linear_step_ms_1000", "nonlinear_step_ms_175",
    "nonlinear_step_ms_1000"}``: median milliseconds per simulator step (module docstring),
    and the 3-D tissue's figures of :func:`riskplan.bench.tissue3d.run` (``tet_*_5k``,
    ``sfepy_linear_step_ms_5k`` where SfePy is installed)."""
    from riskplan.bench import tissue3d

    r_lin = 50 if quick else 300
    r_nl = 10 if quick else 40
    out = {}
    for n in ELEMENTS:
        out[f"linear_step_ms_{n}"] = round(linear_step_ms(n, r_lin), 4)
    for n in ELEMENTS:
        out[f"nonlinear_step_ms_{n}"] = round(nonlinear_step_ms(n, r_nl), 3)
    out.update(tissue3d.run(quick))
    return out
