"""Speed benchmarks behind ``riskplan bench <area> --json``.

Each module ``riskplan.bench.<area>`` defines ``run(quick: bool = False) -> dict``
returning the figures its issue names; the ``bench`` command adds ``machine``
(:func:`machine_info`: CPU model, core count, thread settings) to every area's figures.
Benchmarks measure; tests never assert times.
"""

from riskplan.bench._timing import cpu_model, machine_info, median_time

__all__ = ["cpu_model", "machine_info", "median_time"]
