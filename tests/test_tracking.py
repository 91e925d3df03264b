"""Metric names built from free text (a split's unused reasons) must reach MLflow, not fail a stage."""
from motionsynth.tracking import log_runs, metric_key


def test_metric_key_replaces_characters_mlflow_refuses():
    assert metric_key("unused_reasons.view 54138969 is not in keep.view (55011271)") == \
        "unused_reasons.view 54138969 is not in keep.view _55011271_"
    assert metric_key("val/rel_zv") == "val/rel_zv"


def test_log_runs_accepts_free_text_metric_names(tmp_path, monkeypatch):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    ids = log_runs(tmp_path, "t", [{"run_name": "split", "metrics": {
        "unused_reasons": {"view 54138969 is not in keep.view (55011271)": 3}, "kept": 5}}])
    import mlflow

    run = mlflow.get_run(ids[0])
    assert run.data.metrics["unused_reasons.view 54138969 is not in keep.view _55011271_"] == 3
    assert run.data.metrics["kept"] == 5
