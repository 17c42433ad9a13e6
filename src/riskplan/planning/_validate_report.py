"""The report of a validation (:mod:`riskplan.planning.validate`): its Markdown table and the
warnings for end points that collide; re-exported there."""

from __future__ import annotations

from riskplan.errors import InvalidInputError


def validation_markdown(rows: list[dict]) -> str:
    """Markdown table of :func:`~riskplan.planning.validate.validation_table` rows
    (probabilities in %).

    Parameters
    ----------
    rows : list of dict
        The rows of ``validation_table``.

    Returns
    -------
    str
        The table, one line per row and a final newline.
    """
    head = (
        "| trajectory | eq.-10 bound | eq. 10, any-component bound | MC of the MDN mixtures (95 % CI) "
        "| MC on the robot, tube (95 % CI) | MC on the robot, backbone + disks (95 % CI) |\n"
        "|---|---|---|---|---|---|"
    )
    lines = [head]
    for r in rows:
        lines.append(
            f"| {r['name']} | {100 * r['bound']:.1f} % | {100 * r['bound_union']:.1f} % | {100 * r['mixture_mc']:.1f} % "
            f"[{100 * r['mixture_low']:.1f}, {100 * r['mixture_high']:.1f}] (n = {r['n_mixture']}) | "
            f"{100 * r['robot_mc']:.1f} % [{100 * r['robot_low']:.1f}, {100 * r['robot_high']:.1f}] "
            f"(n = {r['n_robot']}, radius {1000 * r['radius']:.0f} mm) | "
            + (
                f"{100 * r['robot_disks_mc']:.1f} % "
                f"[{100 * r['robot_disks_low']:.1f}, {100 * r['robot_disks_high']:.1f}] |"
                if r.get("robot_disks_mc") is not None
                else "– (retracting base: tube only) |"
            )
        )
    return "\n".join(lines) + "\n"


def endpoint_warnings(rows: list[dict], threshold: float = 0.5) -> list[str]:
    """Warnings for :func:`~riskplan.planning.validate.validation_table` rows whose first or last configuration collides
    on the robot in at least ``threshold`` of the executions.

    Start and goal stay fixed while a trajectory is optimised, so when the robot's body already
    touches an obstacle there, no trajectory between them can do better on the robot, whatever
    its eq.-10 bound: the remedy is a start or goal with clearance. Returns one line per
    affected end point (empty list: nothing to say).
    """
    if not 0.0 < float(threshold) <= 1.0:
        raise InvalidInputError(f"threshold: expected a fraction in (0, 1], got {threshold!r}")
    out = []
    for row in rows:
        per = row.get("robot_per_config") or []
        for label, k in (("start", 0), ("goal", len(per) - 1)):
            if per and per[k] >= threshold:
                out.append(
                    f"{row['name']}: the {label} configuration itself collides in "
                    f"{100 * per[k]:.0f} % of {row['n_robot']} robot executions; no trajectory "
                    f"with this {label} can avoid that (choose one with clearance)"
                )
            if len(per) == 1:
                break
    return out
