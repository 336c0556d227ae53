"""A checkpoint whose weights do not fit the architecture it names (load_state_dict's size mismatch,
or tensors of another architecture) ends every command that loads it in one line naming the file,
the architecture and the first tensor that does not fit: exit 2, no traceback, nothing written.

The checkpoints are untrained (a model built and saved, no training): what is wrong with them is their
shape, which any weights show alike. In-process through `edgepick.cli.run`, as the other tables here.
"""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from edgepick.cli import run  # noqa: E402
from edgepick.files import mark  # noqa: E402
from edgepick.geometry import Size  # noqa: E402
from edgepick.models import ModelConfig, build_model  # noqa: E402
from edgepick.runtime.grasp import DEFAULT_CLASSES  # noqa: E402
from edgepick.train.checkpoint import Checkpoint  # noqa: E402
from edgepick.train.config import TrainConfig  # noqa: E402
from tests.cli.test_bad_input import _fill, _tree, assert_refused  # noqa: E402
from tests.runtime.test_pipeline import red_model  # noqa: E402

FIRST_CONV = "backbone.0.0.weight"  # DeepLabV3-MobileNetV3's first conv: 16 filters of 3x3x3
EPOCHS = 4  # the runs' budget; hybrid-QaT at --qat-fraction 0.25 starts from epoch_003.pt


def _grown(state: dict) -> dict:
    """STATE with the first conv one filter larger: a shape no model of the recorded config has."""
    weight = state[FIRST_CONV]
    return {**state, FIRST_CONV: torch.zeros(weight.shape[0] + 1, *weight.shape[1:])}


VARIANTS = {  # name -> (what changes in a good checkpoint, the words of its refusal)
    "shape": (lambda ck: {"model": _grown(ck["model"])},
              f"does not fit a deeplabv3-mobilenetv3 model with 5 classes: {FIRST_CONV} has shape [17, 3, 3, 3] in "
              "the file, [16, 3, 3, 3] in the model"),
    "arch": (lambda ck: {"model_config": {**ck["model_config"], "arch": "lraspp-mobilenetv3"}},
             "does not fit a lraspp-mobilenetv3 model with 5 classes: the file has no tensor classifier.cbr.0.weight"),
    "classes": (lambda ck: {"model_config": {**ck["model_config"], "num_classes": 7}, "classes": [*ck["classes"], "a", "b"]},
                "does not fit a deeplabv3-mobilenetv3 model with 7 classes: classifier.4.weight has shape "
                "[5, 256, 1, 1] in the file, [7, 256, 1, 1] in the model (1 more of another shape)"),
}


@pytest.fixture(scope="module")
def ws(tmp_path_factory, small_data):
    """Per variant: a checkpoint file, and a float run (last.pt and the kept epoch_003.pt) whose
    checkpoints have that fault; a model for bench."""
    w = tmp_path_factory.mktemp("bad-weights")
    cfg = TrainConfig(data=str(small_data), out=str(w / "run"), epochs=EPOCHS, size=Size(64, 48), keep_epochs=[3],
                      device="cpu")
    good = Checkpoint(model_config=ModelConfig(), classes=DEFAULT_CLASSES, input_size=Size(64, 48),
                      model=build_model(ModelConfig()).state_dict(), train_config=cfg, epoch=EPOCHS,
                      optimizer={}, scheduler={}).to_dict()
    ws = {"W": w, "D": small_data, "MODEL": red_model(w / "model.onnx")}
    for name, (change, _) in VARIANTS.items():
        bad = {**good, **change(good)}
        torch.save(bad, w / f"{name}.pt")
        ws[name] = w / f"{name}.pt"
        run_dir = w / f"run-{name}"  # what --resume reads: its last.pt
        run_dir.mkdir()
        torch.save(bad, run_dir / "last.pt")
        mark(run_dir, "train")
        ws[f"run-{name}"] = run_dir
        start_dir = w / f"start-{name}"  # hybrid-QaT reads last.pt's config, then starts from the kept epoch
        start_dir.mkdir()
        torch.save(good, start_dir / "last.pt")
        torch.save({**bad, "epoch": 3}, start_dir / "epoch_003.pt")
        mark(start_dir, "train")
        ws[f"start-{name}"] = start_dir
    return ws


COMMANDS = {  # every command that loads a checkpoint; {CK} a checkpoint, {RUN} a run whose last.pt is it,
    # {START} a run whose kept epoch (hybrid-QaT's start) is it
    "eval": ["eval", "{CK}", "{D}"],
    "export": ["export", "{CK}", "--out", "{W}/e.onnx"],
    "quantize static": ["quantize", "static", "{CK}", "--data", "{D}", "--out", "{W}/q.onnx"],
    "quantize inspect": ["quantize", "inspect", "{CK}", "--data", "{D}"],
    "bench --gpu-checkpoint": ["bench", "{MODEL}", "--data", "{D}", "--gpu-checkpoint", "{CK}", "--out", "{W}/b"],
    "train --resume": ["train", "{D}", "--out", "{RUN}", "--resume"],
    "quantize hybrid": ["quantize", "hybrid", "{START}", "--data", "{D}", "--qat-fraction", "0.25", "--out",
                        "{W}/h.onnx"],
}
# a checkpoint of 7 classes is refused for its classes first where the command compares them with DATA's
CLASSES_FIRST = {("classes", "quantize static"): "differ from the data set's",
                 ("classes", "quantize inspect"): "differ from the data set's"}
CASES = [(name, command, CLASSES_FIRST.get((name, command), message))
         for name, (_, message) in VARIANTS.items() for command in COMMANDS]


@pytest.mark.parametrize("name, command, message", CASES, ids=[f"{n}-{c}" for n, c, _ in CASES])
def test_weights_that_do_not_fit_are_one_line_exit_2_and_nothing_written(ws, capfd, monkeypatch, name, command,
                                                                          message):
    monkeypatch.chdir(ws["W"])
    places = {**ws, "CK": ws[name], "RUN": ws[f"run-{name}"], "START": ws[f"start-{name}"]}
    before = _tree(ws["W"]), _tree(ws["D"])
    code = run([_fill(a, places) for a in COMMANDS[command]])
    assert_refused(code, *capfd.readouterr(), message)
    assert (_tree(ws["W"]), _tree(ws["D"])) == before, "something was written"
