"""Speed benchmarks behind ``riskplan bench <area> --json``.

Each module ``riskplan.bench.<area>`` defines ``run(quick: bool = False) -> dict``
returning the figures its issue names. Benchmarks measure; tests never assert times.
"""
