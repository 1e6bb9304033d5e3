"""The training step's compute choices (device, precision, memory format), batch prefetching, and
the epoch loop's saves within an epoch."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from odolab.learned.training import (
    SERIAL,
    ComputeConfig,
    DataConfig,
    TrainingData,
    choose_compute,
    make_training_data,
    prefetched,
)
from odolab.learned.training.compute import cpu_flags, native_bf16
from odolab.learned.training.epochs import EpochLoop, EpochTracker

CPU = torch.device("cpu")
X86_BF16 = "processor\t: 0\nflags\t\t: fpu sse avx512f avx512_bf16\n"
X86_PLAIN = "processor\t: 0\nflags\t\t: fpu sse avx2\n"
ARM_BF16 = "processor\t: 0\nFeatures\t: fp asimd bf16 i8mm\n"


def test_auto_picks_bf16_only_where_the_cpu_has_it():
    assert choose_compute(CPU, flags=cpu_flags(X86_BF16)).precision == "bf16"
    assert choose_compute(CPU, flags=cpu_flags(ARM_BF16)).precision == "bf16"
    plain = choose_compute(CPU, flags=cpu_flags(X86_PLAIN))
    assert (plain.precision, plain.memory_format) == ("fp32", "contiguous")
    assert not native_bf16(CPU, set())
    # a recipe's explicit choice wins, even where bf16 is emulated
    forced = choose_compute(CPU, "bf16", "channels_last", flags=set())
    assert (forced.precision, forced.memory_format) == ("bf16", "channels_last")
    assert choose_compute(CPU, "fp32", flags=cpu_flags(X86_BF16)).precision == "fp32"


def test_the_device_is_a_gpu_when_present_else_the_cpu(monkeypatch):
    from odolab.learned.training import pick_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert pick_device().type in ("cpu", "mps")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert pick_device().type == "cuda"
    # on a CUDA device, auto is bf16 where the GPU supports it, else fp32
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: True)
    assert choose_compute(torch.device("cuda"), flags=set()).precision == "bf16"
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: False)
    assert choose_compute(torch.device("cuda"), flags=cpu_flags(X86_BF16)).precision == "fp32"


def test_a_bad_compute_table_is_refused_in_one_line():
    for bad in (
        {"precision": "fp16"},
        {"memory_format": "nhwc"},
        {"loader_workers": -1},
        {"loader_workers": True},
        {"loader_workers": "many"},
    ):
        with pytest.raises(ValueError, match=next(iter(bad))):
            ComputeConfig(**bad)


def test_a_compute_table_says_what_each_field_takes():
    """Its choices and range come from the fields, for errors and :func:`odolab.config.describe` alike."""
    from odolab.config import describe

    assert [(r.name, r.value, r.range) for r in describe(ComputeConfig)] == [
        ("precision", "auto", "one of 'auto', 'fp32', 'bf16'"),
        ("memory_format", "auto", "one of 'auto', 'contiguous', 'channels_last'"),
        ("loader_workers", "auto", "'auto' or [0, 64]"),
        ("loader_thread", "auto", "one of 'auto', 'on', 'off'"),
    ]
    assert all(r.doc for r in describe(ComputeConfig()))
    for bad, said in (
        ({"precision": "fp16"}, "precision must be one of 'auto', 'fp32', 'bf16', got 'fp16'"),
        ({"loader_workers": 65}, "loader_workers must be 'auto' or in [0, 64], got 65"),
        ({"loader_workers": 1.0}, "loader_workers must be 'auto' or a whole number in [0, 64], got 1.0"),
    ):
        with pytest.raises(ValueError) as info:
            ComputeConfig(**bad)
        assert str(info.value) == said


def test_loader_workers_auto_is_none_on_two_cores_and_one_on_more():
    assert ComputeConfig().resolve(CPU, cores=2).loader_workers == 0
    assert ComputeConfig().resolve(CPU, cores=8).loader_workers == 1
    assert ComputeConfig(loader_workers=3).resolve(CPU, cores=2).loader_workers == 3
    assert not ComputeConfig().resolve(CPU, cores=8).loader_thread


def test_on_a_gpu_auto_makes_batches_in_the_training_process():
    """On a GPU the loader only reads frames and the GPU makes the inputs: no worker process, however
    many cores (docs/training.md#gpus); explicit choices are kept."""
    gpu = torch.device("mps")  # resolve() needs no such hardware; any non-CPU device is a GPU here
    auto = ComputeConfig().resolve(gpu, cores=16)
    assert (auto.loader_workers, auto.loader_thread) == (0, False)
    assert ComputeConfig(loader_thread="on").resolve(gpu, cores=16).loader_thread is True
    kept = ComputeConfig(loader_workers=4).resolve(gpu, cores=16)
    assert (kept.loader_workers, kept.loader_thread) == (4, False)


def test_a_compute_table_is_read_from_toml(tmp_path):
    from odolab.learned.training import from_toml

    path = tmp_path / "c.toml"
    path.write_text('precision = "fp32"\nloader_workers = "auto"\n')
    assert from_toml(ComputeConfig, path) == ComputeConfig(precision="fp32")
    path.write_text("loader_workers = 2\n")
    assert from_toml(ComputeConfig, path).loader_workers == 2
    path.write_text('loader_workers = "two"\n')
    with pytest.raises(ValueError, match="loader_workers"):
        from_toml(ComputeConfig, path)


def test_bf16_autocast_runs_a_step_and_returns_fp32_losses():
    c = choose_compute(CPU, "bf16")
    net = c.prepare(torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.Flatten(), torch.nn.LazyLinear(3)))
    with c.autocast():
        out = net(c.inputs(torch.rand(2, 3, 8, 8)))
    assert out.dtype == torch.bfloat16
    loss = out.float().pow(2).mean()
    loss.backward()
    assert all(p.grad is not None and p.grad.dtype == torch.float32 for p in net.parameters())


def _square(k: int) -> int:
    return k * k


@pytest.mark.parametrize("workers", [0, 1, 2])
@pytest.mark.parametrize("thread", [False, True])
def test_prefetched_batches_come_in_order(workers, thread):
    assert list(prefetched(list(range(7)), _square, workers, thread=thread)) == [k * k for k in range(7)]


def test_a_loader_thread_runs_ahead_and_stops_with_an_abandoned_iteration():
    import time

    made: list[int] = []

    def make(k: int) -> int:
        made.append(k)
        return k

    it = iter(prefetched(list(range(100)), make, 0, ahead=2, thread=True))
    assert next(it) == 0
    waited = time.monotonic() + 10
    while len(made) < 3 and time.monotonic() < waited:  # made ahead while the consumer holds batch 0
        time.sleep(0.01)
    it.close()  # the consumer stops (a deadline): nothing more is made
    time.sleep(0.05)
    assert made == [0, 1, 2]


def test_a_loader_thread_is_made_only_when_asked_and_only_without_workers():
    assert not ComputeConfig().resolve(CPU, cores=2).loader_thread
    on = ComputeConfig(loader_thread="on").resolve(CPU, cores=8)
    assert on.loader_thread and on.loader_workers == 0  # 'on' means the batches are made in this process
    with pytest.raises(ValueError, match="expected loader_workers 0 or 'auto' with it, got 2"):
        ComputeConfig(loader_thread="on", loader_workers=2)


def _toy_run(path, batches_before_kill: int | None, save_every: float) -> dict:
    """One epoch of 6 batches of a toy regression; killed after ``batches_before_kill`` batches."""
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.Dropout(0.5), torch.nn.Linear(8, 1))
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    loop = EpochLoop(path, {"net": net}, opt, 1, 3, {"toy": 1}, save_every=save_every)
    loop.resume()
    x, y = torch.rand(48, 4, generator=torch.Generator().manual_seed(1)), torch.rand(48, 1)

    class Killed(Exception):
        pass

    def train_epoch(epoch: int, rng: np.random.Generator, tracker: EpochTracker) -> dict:
        order = rng.permutation(48)
        for b in range(tracker.start, 6):
            if batches_before_kill is not None and b == batches_before_kill:
                raise Killed()
            idx = torch.from_numpy(order[b * 8 : (b + 1) * 8])
            loss = (net(x[idx]) - y[idx]).pow(2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            tracker.add(loss.item(), len(idx))
        return {}

    try:
        loop.run(train_epoch, lambda epoch: [])
    except Killed:
        return {}
    return {"weights": [p.detach().clone() for p in net.parameters()], "row": loop.curves.rows[0]}


def test_a_run_killed_within_an_epoch_resumes_to_the_same_numbers(tmp_path):
    whole = _toy_run(tmp_path / "whole.pt", None, 600.0)
    assert _toy_run(tmp_path / "split.pt", 4, 0.0) == {}  # killed after 4 of 6 batches, each saved
    resumed = _toy_run(tmp_path / "split.pt", None, 0.0)
    for a, b in zip(whole["weights"], resumed["weights"]):
        assert torch.equal(a, b)
    assert resumed["row"]["pairs"] == whole["row"]["pairs"] == 48
    assert resumed["row"]["loss"] == pytest.approx(whole["row"]["loss"], rel=1e-12)


def test_a_compacted_state_keeps_the_networks_not_the_optimiser_and_still_resumes(tmp_path):
    from odolab.learned.training.checkpoints import load_checkpoint, save_checkpoint
    from odolab.learned.training.epochs import STATE_FORMAT, STATE_KIND

    whole = _toy_run(tmp_path / "whole.pt", None, 600.0)
    assert "optimizer" in load_checkpoint(tmp_path / "whole.pt", STATE_KIND, STATE_FORMAT)
    net = torch.nn.Linear(1, 1)
    EpochLoop(tmp_path / "whole.pt", {}, torch.optim.Adam(net.parameters()), 1, 3, {"toy": 1}).compact()
    doc = load_checkpoint(tmp_path / "whole.pt", STATE_KIND, STATE_FORMAT)
    assert "optimizer" not in doc and doc["epoch"] == 1
    again = _toy_run(tmp_path / "whole.pt", None, 600.0)  # finished: loads, trains nothing more
    for a, b in zip(whole["weights"], again["weights"]):
        assert torch.equal(a, b)
    assert again["row"] == whole["row"]
    assert _toy_run(tmp_path / "split.pt", 4, 0.0) == {}
    EpochLoop(tmp_path / "split.pt", {}, torch.optim.Adam(net.parameters()), 1, 3, {"toy": 1}).compact()
    assert "optimizer" in load_checkpoint(tmp_path / "split.pt", STATE_KIND, STATE_FORMAT)  # not finished
    _toy_run(tmp_path / "split.pt", None, 600.0)
    (tmp_path / "split.pt").chmod(0o444)  # a read-only finished state is left as it is
    EpochLoop(tmp_path / "split.pt", {}, torch.optim.Adam(net.parameters()), 1, 3, {"toy": 1}).compact()
    assert "optimizer" in load_checkpoint(tmp_path / "split.pt", STATE_KIND, STATE_FORMAT)
    doc["epoch"] = 0  # a compacted state cannot train on
    save_checkpoint(tmp_path / "cut.pt", STATE_KIND, STATE_FORMAT, doc)
    with pytest.raises(ValueError, match=r"cut.pt: field optimizer: expected the optimiser's state .*got none"):
        _toy_run(tmp_path / "cut.pt", None, 600.0)


@pytest.mark.slow
def test_bench_training_prints_and_writes_one_row_per_recipe(tmp_path, capsys):
    """``python -m odolab.bench --only training --recipe R --json F`` on a tiny recipe."""
    import json

    from odolab.cli import bench

    recipe = tmp_path / "tiny.toml"
    recipe.write_text(
        f"""data_root = "{tmp_path / "data"}"
val_pairs = 20
[model]
width = 64
height = 36
base_planes = 8
groups = 4
hidden = 32
compress_channels = 8
warp = "nominal"
mirror_turns = true
[train_data]
episodes = 2
max_steps = 16
width = 64
height = 36
[val_data]
split = "val"
episodes = 1
max_steps = 12  # the bench renders 20 such episodes
width = 64
height = 36
[[stages]]
name = "forward"
actions = ["move_forward"]
epochs = 1
batch = 4
""",
        encoding="utf-8",
    )
    out = tmp_path / "bench.json"
    import torch

    threads = torch.get_num_threads()
    assert bench.main(["--only", "training", "--recipe", str(recipe), "--json", str(out), "--train-threads", "1"]) == 0
    rows = json.loads(out.read_text())["training"]
    assert len(rows) == 1 and rows[0]["config"] == "tiny"
    assert rows[0]["threads"] == 1 and torch.get_num_threads() == threads  # restored after the part
    for key in (
        "bare_pairs_per_s", "end_to_end_pairs_per_s", "fp32_bare_pairs_per_s", "normaliser_moments_ms",
        "tensor_var_moments_ms", "end_to_end_between_steps_pairs_per_s", "end_to_end_thread_pairs_per_s",
    ):  # fmt: skip
        assert rows[0][key] > 0
    chosen = "thread" if rows[0]["loader_thread"] else "between_steps"  # the chosen way is one of the two timed
    assert (
        rows[0]["loader_workers"] > 0
        or rows[0][f"end_to_end_{chosen}_pairs_per_s"] == rows[0]["end_to_end_pairs_per_s"]
    )
    assert rows[0]["precision"] in ("fp32", "bf16") and rows[0]["memory_format"] == "contiguous"
    assert "end_to_end_pairs_per_s" in capsys.readouterr().out
    # the end-to-end epoch on a given data folder: one val episode of 40 steps holds fewer forward
    # pairs than the 24 batches of 4 take, so they are repeated
    folder = tmp_path / "given"
    make_training_data(DataConfig(split="val", episodes=1, max_steps=40, width=64, height=36), folder, execution=SERIAL)
    assert TrainingData(folder).counts()["move_forward"] < 24 * 4
    args = ["--only", "training", "--recipe", str(recipe), "--json", str(out), "--bench-data", str(folder)]
    assert bench.main([*args, "--train-threads", "1"]) == 0
    rows = json.loads(out.read_text())["training"]
    assert rows[0]["data"] == str(folder) and rows[0]["end_to_end_pairs_per_s"] > 0
    assert rows[0]["data_pairs"] == TrainingData(folder).counts()["move_forward"]
    # refused before any timing, naming what is wrong
    from odolab.cli import UsageError

    (tmp_path / "a-file").write_text("")
    turns = tmp_path / "turns"  # one step: a turn
    make_training_data(DataConfig(split="val", episodes=1, max_steps=1, width=64, height=36), turns, execution=SERIAL)
    assert TrainingData(turns).counts()["move_forward"] == 0
    for given, said in [
        ("", "expected a training-data folder"),
        (str(tmp_path / "nowhere"), "nowhere: no such folder"),
        (str(tmp_path / "a-file"), "a-file: not a folder"),
        (str(turns), "turns: no pairs for the first stage ('forward': move_forward)"),
    ]:
        with pytest.raises(UsageError, match=re.escape(said)):
            bench.main(["--only", "training", "--recipe", str(recipe), "--bench-data", given])


def test_the_projection_filters_only_its_band_with_the_same_numbers():
    """psi's S-proj smooths the projected rows and their neighbours only: the same numbers, bit for
    bit, as filtering the whole image first (the plain definition, written out here)."""
    import torch.nn.functional as F

    from odolab.api import Intrinsics
    from odolab.learned.robust_vo.inputs import top_down_projection

    rng = np.random.default_rng(0)
    depth = torch.from_numpy(rng.uniform(0.0, 8.0, (3, 48, 85)).astype(np.float32))
    depth[:, ::7] = 0.0  # holes
    K = Intrinsics(40.0, 40.0, 42.0, 23.5, 85, 48)

    def reference(d: torch.Tensor, rows: float) -> torch.Tensor:
        b, h, w = d.shape
        valid = (d > 0).to(d.dtype)
        padded = F.pad(torch.stack([d * valid, valid], dim=1), (1, 1, 1, 1), mode="replicate")
        smooth, share = F.avg_pool2d(padded, 3, stride=1).unbind(1)
        z = torch.where(valid > 0, smooth / share.clamp_min(1e-6), torch.zeros_like(d))
        keep = max(1, int(round(rows * h)))
        top = (h - keep) // 2
        z = z[:, top : top + keep]
        u = torch.arange(w, dtype=d.dtype)
        x = (u - K.cx) / K.fx * z
        x_max = 10.0 * (K.cx + 0.5) / K.fx
        col = torch.floor((x + x_max) / (2 * x_max) * w).long()
        row = (h - 1) - torch.floor((z - 0.1) / (10.0 - 0.1) * h).long()
        ok = (z >= 0.1) & (z <= 10.0) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        image = torch.arange(b)[:, None, None].expand_as(z)
        counts = torch.bincount((image * h * w + row * w + col)[ok], minlength=b * h * w).reshape(b, h, w).to(d.dtype)
        return counts / counts.flatten(1).amax(dim=1).clamp_min(1.0)[:, None, None]

    for d in (depth, depth.double()):  # the box filter's sums are avg_pool2d's in either precision
        for rows in (100 / 192, 1.0, 0.01):
            assert torch.equal(top_down_projection(d, K, 10.0, rows), reference(d, rows))


def test_a_state_that_is_a_link_to_nothing_is_refused_not_written_through(tmp_path):
    state = tmp_path / "work" / "forward.pt"
    state.parent.mkdir()
    state.symlink_to(tmp_path / "elsewhere.pt")
    with pytest.raises(ValueError, match=r"forward.pt: is a link to nothing \(.*elsewhere.pt\); remove it"):
        _toy_run(state, None, save_every=600.0)
    assert not (tmp_path / "elsewhere.pt").exists()


def test_reports_of_another_recipe_are_named(tmp_path):
    from odolab.learned.training.validation import other_training

    cmd = "python -m odolab.learned.robust_vo.train --config studies/robust_vo/shipped.toml --set seed=1 --hours 2"
    assert other_training(tmp_path, cmd) is None  # nothing there yet
    (tmp_path / "training.json").write_text(json.dumps({"command": cmd.replace("--hours 2", "--quiet")}))
    assert other_training(tmp_path, cmd) is None  # the same recipe, another chunk
    for longer in ("--set epochs=3", "--set stages.forward.epochs=8", "--set=stages.0.epochs=2"):
        assert other_training(tmp_path, f"{cmd} {longer}") is None  # the same training, given more epochs
    for other in (
        "python -m odolab.learned.deepvo.train --config studies/deepvo/shipped.toml --set seed=1",
        "python -m odolab.learned.robust_vo.train --config=studies/robust_vo/shipped-341.toml --set seed=1",
        "python -m odolab.learned.robust_vo.train --config studies/robust_vo/shipped.toml",
    ):
        (tmp_path / "training.json").write_text(json.dumps({"command": other}))
        assert "is the summary of another training" in other_training(tmp_path, cmd)
    (tmp_path / "training.json").write_text("{")
    assert "not a readable training summary" in other_training(tmp_path, cmd)
    (tmp_path / "training.json").write_text(
        json.dumps({"command": cmd + " --set data_root=/big/disk --set compute.precision=fp32"})
    )
    assert other_training(tmp_path, cmd) is None  # where and how it computed: the same training


@pytest.mark.parametrize(
    ("name", "said"),
    [
        ("", "device '': expected cpu, cuda, cuda:N or mps"),
        ("cpu:1", "device 'cpu:1': expected cpu, cuda, cuda:N or mps"),
        ("tpu", "device 'tpu': expected cpu, cuda, cuda:N or mps"),
        ("cuda:-1", "device 'cuda:-1': expected cpu, cuda, cuda:N or mps"),
        ("cuda:2", "device 'cuda:2': this machine has 1 CUDA GPU (cuda:0)"),
    ],
)
def test_a_device_name_is_one_of_four_forms_and_on_this_machine(monkeypatch, name, said):
    from odolab.learned.training import pick_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    with pytest.raises(ValueError) as info:
        pick_device(name)
    assert str(info.value) == said
    assert pick_device("cuda:0").type == "cuda" and pick_device("cpu").type == "cpu"
