"""``riskplan reproduce``: :mod:`~riskplan.app.reproduce.pipeline` runs the stages; one module
per paper (:mod:`~riskplan.app.reproduce.mdn`: the MDN kinematics paper;
:mod:`~riskplan.app.reproduce.deformable`: the deformable-tissue paper, Fig. 6) and the
studies beside them; :mod:`~riskplan.app.reproduce.report` writes the report."""
