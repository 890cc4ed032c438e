"""The Speed page is rendered from the benchmark JSON, numbers and commands as the scripts printed them."""

from __future__ import annotations

import json

from icprl_lightning.reproduce.speed import speed_page


def test_each_benchmark_json_becomes_a_table_with_its_command(tmp_path):
    training = {"benchmark": "training_samples_per_second", "command": "python benchmarks/training_throughput.py",
                "torch_threads": 2, "results": {"dpt_small_4L_32d_b64": {
                    "dpt_reference": {"samples_per_s": 1000.0, "predictions_per_sample": 100},
                    "4head_k100": {"samples_per_s": 431.4, "predictions_per_sample": 100, "vs_reference": 0.43,
                                   "default": True}}}}
    deployment = {"benchmark": "deployment_env_steps_per_second", "tasks": 100,
                  "results": {"dpt_small_4L_32d": {"kv_cache": 34005, "kv_cache_vs_reference": 14.6}}}
    (tmp_path / "speed_training.json").write_text(json.dumps(training))
    (tmp_path / "speed_deploy100.json").write_text(json.dumps(deployment))
    (tmp_path / "notes.json").write_text(json.dumps({"not": "a benchmark"}))
    page = speed_page(tmp_path)
    assert "Command: `python benchmarks/training_throughput.py`." in page
    assert "| 4head_k100 | 431 | 100 | 0.43 | yes |" in page
    assert "| dpt_small_4L_32d | 34,005 | 14.60 |" in page
    assert "predates the `command` key" in page  # the deployment JSON carries no command
    assert "notes" not in page


def test_a_folder_without_benchmark_json_has_no_page(tmp_path):
    (tmp_path / "x.json").write_text("{}")
    assert speed_page(tmp_path) is None
