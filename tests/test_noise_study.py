"""The noise-robustness study resumes what it finished, and reruns rows whose model file changed."""
import json

import studies.noise_robustness as study


def test_noise_study_resumes_and_reruns_changed_weights(tmp_path, monkeypatch):
    doc = study.run_study(tmp_path, ["action-prior"], [2.0], episodes=1, max_steps=3, parallel=False)
    assert set(doc["results"]) == {"1/action-prior", "2/action-prior"}
    assert doc["results"]["1/action-prior"]["weights"] is None  # not a learned odometer
    calls = []
    real = study.run_comparison

    def counting(config):
        calls.append(config.noise.rgb)
        return real(config)

    monkeypatch.setattr(study, "run_comparison", counting)
    study.run_study(tmp_path, ["action-prior"], [2.0], episodes=1, max_steps=3, parallel=False)
    assert calls == []  # everything was done
    path = tmp_path / "results.json"
    saved = json.loads(path.read_text())
    saved["results"]["2/action-prior"]["weights"] = "0" * 64  # as if made by another model file
    path.write_text(json.dumps(saved))
    again = study.run_study(tmp_path, ["action-prior"], [2.0], episodes=1, max_steps=3, parallel=False)
    assert calls == [2.0]
    assert again["results"]["2/action-prior"]["weights"] is None
