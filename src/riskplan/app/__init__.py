"""The application layer: what the commands run and write, above both wings.

* :mod:`riskplan.app.demo`: the ``riskplan demo`` stages, one module per area;
* :mod:`riskplan.app.reproduce`: ``riskplan reproduce``, one module per paper
  (:mod:`~riskplan.app.reproduce.mdn`, :mod:`~riskplan.app.reproduce.deformable`) and the
  studies beside them;
* :mod:`riskplan.app.outputs`: the files that ``plan``, ``collision table`` and the like write;
* :mod:`riskplan.app.report` (the HTML report), :mod:`riskplan.app.store` (resumable records).

Functions here compute first and plot only when asked; plotting libraries are imported
inside the plotting functions. Library code never imports this package.
"""
