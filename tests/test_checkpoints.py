"""odolab/learned/training/checkpoints.py: model files and training states carry a checksum, checked on load;
one trainer never replaces another's model; an export or --init that is a dead link is named as one."""

from __future__ import annotations

import hashlib
import struct
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")  # a declared dependency; skip only where it is truly absent


from odolab.learned.training import CheckpointError, checkpoints
from tests.helpers import robust_job

KIND = "odolab-test-model"


@dataclass(frozen=True)
class TinyModel:
    width: int = 3


@dataclass(frozen=True)
class TinyRecipe:
    model: TinyModel = field(default_factory=TinyModel)
    seed: int = 0


def _build(cfg: TinyModel) -> dict[str, torch.nn.Module]:
    return {"net": torch.nn.Linear(cfg.width, 2)}


def _saved(path: Path) -> dict[str, torch.nn.Module]:
    torch.manual_seed(0)
    nets = _build(TinyModel())
    checkpoints.save_model(path, KIND, TinyRecipe(), nets, {"epochs": 1})
    return nets


def _load(path: Path, shipped: checkpoints.Shipped | None = None):
    return checkpoints.load_model(path, KIND, TinyModel, _build, shipped)


def _flip_bit_in_first_tensor(path: Path) -> None:
    """Flip the lowest bit of the first byte of the first tensor's data inside the zip file, as a
    disk or a copy would (torch's reader checks no CRC)."""
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info = next(i for i in z.infolist() if "/data/" in i.filename and i.file_size > 0)
    name_len, extra_len = struct.unpack("<HH", data[info.header_offset + 26 : info.header_offset + 30])
    data[info.header_offset + 30 + name_len + extra_len] ^= 0x01
    path.write_bytes(bytes(data))


def test_an_intact_model_loads_with_its_weights_and_no_note(tmp_path, capsys):
    nets = _saved(tmp_path / "m.pt")
    assert isinstance(torch.load(tmp_path / "m.pt", weights_only=True)[checkpoints.CHECKSUM_KEY], str)
    _, loaded, _ = _load(tmp_path / "m.pt")
    for key, value in nets["net"].state_dict().items():
        assert torch.equal(value, loaded["net"].state_dict()[key])
    assert capsys.readouterr().err == ""


def test_a_flipped_bit_in_a_models_weights_is_refused_in_one_line(tmp_path):
    _saved(tmp_path / "m.pt")
    _flip_bit_in_first_tensor(tmp_path / "m.pt")
    with pytest.raises(CheckpointError) as err:
        _load(tmp_path / "m.pt")
    message = str(err.value)
    assert message.startswith(f"{tmp_path / 'm.pt'}: damaged: its contents do not match the checksum")
    assert "\n" not in message


def test_a_changed_weight_saved_by_hand_is_refused(tmp_path):
    _saved(tmp_path / "m.pt")
    doc = torch.load(tmp_path / "m.pt", weights_only=True)
    weight = doc["networks"]["net"]["weight"]
    weight.view(torch.int32).view(-1)[0] ^= 1  # one bit of one float32
    torch.save(doc, tmp_path / "edited.pt")
    with pytest.raises(CheckpointError, match=r"edited.pt: damaged"):
        _load(tmp_path / "edited.pt")


def test_a_flipped_bit_in_a_training_state_is_refused(tmp_path):
    state = {"epoch": 2, "modules": {"net": torch.nn.Linear(3, 2).state_dict()}, "curves": [{"loss": 0.5}]}
    checkpoints.save_checkpoint(tmp_path / "s.pt", "odolab-training-state", 2, state)
    assert checkpoints.load_checkpoint(tmp_path / "s.pt", "odolab-training-state", 2)["epoch"] == 2
    _flip_bit_in_first_tensor(tmp_path / "s.pt")
    with pytest.raises(CheckpointError, match=r"s.pt: damaged: its contents do not match"):
        checkpoints.load_checkpoint(tmp_path / "s.pt", "odolab-training-state", 2)


def test_saving_a_loaded_checkpoint_again_replaces_its_checksum(tmp_path):
    """A state rewritten without a part (a finished stage drops its optimiser) gets a fresh checksum."""
    doc = {"epoch": 1, "optimizer": {"state": {0: {"step": torch.tensor(3.0)}}, "param_groups": [{"lr": 1e-3}]}}
    checkpoints.save_checkpoint(tmp_path / "s.pt", "odolab-training-state", 2, doc)
    loaded = checkpoints.load_checkpoint(tmp_path / "s.pt", "odolab-training-state", 2)
    loaded.pop("optimizer")
    checkpoints.save_checkpoint(tmp_path / "s.pt", "odolab-training-state", 2, loaded)
    assert "optimizer" not in checkpoints.load_checkpoint(tmp_path / "s.pt", "odolab-training-state", 2)


def test_a_file_written_before_checksums_loads_with_a_one_line_note(tmp_path, capsys):
    _saved(tmp_path / "m.pt")
    doc = torch.load(tmp_path / "m.pt", weights_only=True)
    del doc[checkpoints.CHECKSUM_KEY]
    torch.save(doc, tmp_path / "old.pt")
    _load(tmp_path / "old.pt")
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"note: {tmp_path / 'old.pt'}: written before odolab kept checksums")


def test_the_shipped_file_without_a_checksum_must_match_its_bytes_digest(tmp_path, capsys):
    _saved(tmp_path / "m.pt")
    doc = torch.load(tmp_path / "m.pt", weights_only=True)
    del doc[checkpoints.CHECKSUM_KEY]
    torch.save(doc, tmp_path / "shipped.pt")
    shipped = checkpoints.Shipped(
        tmp_path / "shipped.pt", hashlib.sha256((tmp_path / "shipped.pt").read_bytes()).hexdigest()
    )
    _load(tmp_path / "shipped.pt", shipped)
    (tmp_path / "copy.pt").write_bytes((tmp_path / "shipped.pt").read_bytes())
    _load(tmp_path / "copy.pt", shipped)  # a copy of it elsewhere is as good
    assert capsys.readouterr().err == ""  # no note for the shipped file
    _flip_bit_in_first_tensor(tmp_path / "shipped.pt")
    with pytest.raises(CheckpointError, match=r"shipped.pt: damaged: the shipped model's bytes do not match"):
        _load(tmp_path / "shipped.pt", shipped)


def test_the_shipped_models_match_their_recorded_digests():
    """Both shipped models verify: by their bytes (written before checksums) or their own checksum."""
    from odolab.learned.deepvo import odometer as deepvo
    from odolab.learned.robust_vo import checkpoint as robust_vo

    for module in (robust_vo, deepvo):
        doc_has_checksum = checkpoints.CHECKSUM_KEY in torch.load(module.SHIPPED, weights_only=True, mmap=True)
        digest = hashlib.sha256(module.SHIPPED.read_bytes()).hexdigest()
        assert doc_has_checksum or digest == module.SHIPPED_SHA256, module.SHIPPED


def test_the_content_digest_ignores_key_order_and_sees_every_value():
    t = torch.arange(4, dtype=torch.float16)
    a = {"kind": "k", "format": 1, "w": t, "n": {2: 1.0, "x": [1, (2, None)]}}
    b = {"n": {"x": [1, (2, None)], 2: 1.0}, "w": t.clone(), "format": 1, "kind": "k"}
    assert checkpoints.content_digest(a) == checkpoints.content_digest(b)
    for changed in (
        {**a, "w": t.to(torch.float32)},  # same values, another dtype
        {**a, "w": t.reshape(2, 2)},  # another shape
        {**a, "n": {2: 1, "x": [1, (2, None)]}},  # an int for a float
        {**a, "n": {2: 1.0, "x": [1, [2, None]]}},  # a list for a tuple
        {**a, "format": 2},
    ):
        assert checkpoints.content_digest(changed) != checkpoints.content_digest(a)
    assert checkpoints.content_digest({**a, checkpoints.CHECKSUM_KEY: "x"}) == checkpoints.content_digest(a)


def test_one_trainer_never_replaces_anothers_model(tmp_path):
    torch = pytest.importorskip("torch")
    import dataclasses

    from odolab.learned.training.checkpoints import CheckpointError, check_export, save_model

    @dataclasses.dataclass
    class R:
        model: dict = dataclasses.field(default_factory=dict)

    model = tmp_path / "model.pt"
    save_model(model, "odolab-robust-vo", R(), {"net": torch.nn.Linear(2, 2)}, {})
    with pytest.raises(ValueError, match="another trainer's"):
        check_export(model, tmp_path / "r.toml", {}, kind="odolab-deepvo")
    with pytest.raises(CheckpointError, match="another trainer's"):
        save_model(model, "odolab-deepvo", R(), {"net": torch.nn.Linear(2, 2)}, {})
    check_export(model, tmp_path / "r.toml", {}, kind="odolab-robust-vo")  # its own trainer may
    save_model(model, "odolab-robust-vo", R(), {"net": torch.nn.Linear(2, 2)}, {})


def test_an_export_that_is_a_dangling_link_is_named_as_one(tmp_path):
    from odolab.learned.training.checkpoints import check_export

    (tmp_path / "model.pt").symlink_to(tmp_path / "nowhere.pt")
    with pytest.raises(ValueError, match="link to nothing"):
        check_export(tmp_path / "model.pt", tmp_path / "r.toml", {})


def test_an_init_that_is_a_dead_link_or_absolute_is_named_as_such(tmp_path):
    from odolab.learned.training.checkpoints import load_init

    def never(path):
        raise AssertionError("not to be loaded")

    dead = tmp_path / "model.pt"
    dead.symlink_to(tmp_path / "gone.pt")
    with pytest.raises(ValueError, match=r"is a link to nothing"):
        load_init(str(dead), tmp_path / "export.pt", never)
    with pytest.raises(ValueError) as caught:
        load_init(str(tmp_path / "none.pt"), tmp_path / "export.pt", never)
    assert "no such model file;" in str(caught.value) and "relative to" not in str(caught.value)
    with pytest.raises(ValueError, match=r"relative to"):
        load_init("no/such/model.pt", tmp_path / "export.pt", never)


def test_a_pipe_a_link_to_nothing_and_a_pickle_each_say_what_they_are_in_one_line(tmp_path, recwarn):
    import os
    import pickle

    fifo, dangling, pickled = tmp_path / "fifo.pt", tmp_path / "dangling.pt", tmp_path / "pickled.pt"
    os.mkfifo(fifo)
    dangling.symlink_to(tmp_path / "nowhere.pt")
    pickled.write_bytes(pickle.dumps({"kind": "odolab-model"}, protocol=4))
    for path, said in (
        (fifo, "a pipe, device or socket, not a checkpoint file"),
        (dangling, "a link to nothing, not a checkpoint file"),
        (tmp_path / "missing.pt", "no such checkpoint file"),
        (pickled, "not a readable torch checkpoint"),
    ):
        with pytest.raises(CheckpointError) as err:
            checkpoints.load_checkpoint(path, "odolab-model", 1)
        assert str(err.value).startswith(f"{path}: {said}") and "\n" not in str(err.value)
    assert not [w for w in recwarn if "pickle" in str(w.message)]  # torch's warning before the refusal: not shown


def test_an_export_never_replaces_the_recipe_a_state_or_a_file_it_did_not_write(tmp_path):
    pytest.importorskip("torch")
    from odolab.cli import UsageError
    from odolab.learned.training import save_checkpoint

    recipe = tmp_path / "recipe.toml"
    with pytest.raises(
        UsageError, match="--export .*recipe.toml: expected a new file or a model odolab exported, found the recipe"
    ):
        robust_job(tmp_path, "--export", str(recipe))
    assert "[[stages]]" in recipe.read_text()
    with pytest.raises(UsageError, match="found the file where stage 'forward' keeps its training state"):
        robust_job(tmp_path, "--export", str(tmp_path / "work" / "forward.pt"))
    # a stage named "model": its state is where the model goes by default
    with pytest.raises(
        UsageError, match=r"stage 'model' keeps its training state.*default --export is <work>/model.pt"
    ):
        robust_job(tmp_path, stage="model")
    state = tmp_path / "elsewhere.pt"
    save_checkpoint(state, "odolab-training-state", 1, {"epoch": 1})
    data = tmp_path / "shard.npz"
    data.write_bytes(b"PK\x03\x04 not a model")
    for path, found in ((state, "found a training state"), (data, "found a file that is not an odolab model")):
        before = path.read_bytes()
        with pytest.raises(UsageError, match=found):
            robust_job(tmp_path, "--export", str(path))
        assert path.read_bytes() == before
    job = robust_job(tmp_path, "--export", str(tmp_path / "new.pt"))  # a new file is fine
    assert job.export == tmp_path / "new.pt"
