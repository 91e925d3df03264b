"""The ``evaluate`` stage: trained runs of one dataset -> the papers' tables, measured on the test split.

A dataset's config names the *suites* that apply to it (``conf/dataset/<ds>.yaml: evaluate.suites``).
A suite is one module of this package with a function ``run(ctx: EvalContext) -> None`` that adds
result rows (:class:`~.context.Row`), error-versus-horizon curves and animation samples to the
context. Adding a protocol is one new module here plus its name in a dataset config:

* ``locomotion``    VAE-LSTM Tables 1-2 (motion / pose prediction error), bandai2_locomotion
* ``mmd``           GlocalNet Table 3 (MMD_avg / MMD_seq) with calibration rows, h36m
* ``horizon``       GlocalNet Table 4 (Euclidean error per frame at 80..640 ms), cmu_aclstm
* ``interpolation`` GlocalNet Table 1 (LocGen against linear interpolation), bandai1
* ``generative``    beyond the papers: FID, recognition accuracy, diversity, multimodality,
                    foot skating, bone-length error

:func:`evaluate` runs the suites and writes (``paths`` from the config):

* ``reports/eval/<ds>/results.csv``: one row per (table, method, column), the columns of
  ``published_results.csv`` plus ``std``, ``n``, ``seeds``, ``key``, ``protocol``, ``run``;
* ``reports/metrics/<ds>.json``: DVC metrics ``{method: {key: mean}}``; the same numbers are
  logged to MLflow, one run ``evaluate:<method>`` per method with metrics ``test/<key>``;
* ``reports/plots/<ds>/<curve>.csv``: ``method, horizon, value`` rows for ``dvc plots``;
* ``data/samples/<ds>.npz``: fixed test sequences, ground truth and every method's
  output in global positions, for the animations of the ``report`` stage.
"""

from .context import EvalContext, Row, evaluate, log_to_mlflow  # noqa: F401
