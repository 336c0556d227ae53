"""The QaT graph's life: BatchNorm literals through torchao's rewrites, a calibrated start (static PTQ's
ranges), the eval copy, carried optimizer moments, loading a checkpoint back."""

from __future__ import annotations

import pytest
import torch

from edgepick.geometry import Size
from edgepick.train.checkpoint import Checkpoint


@pytest.fixture(scope="module")
def fresh_qat() -> torch.fx.GraphModule:
    """One untrained DeepLabV3-MobileNetV3 (the default ModelConfig, seed 0) prepared for QaT at 96x64, built once
    for the tests that only look at or train such a graph: they take a copy.deepcopy of it. A copy's
    train()/eval() act on the original: switch copies with edgepick.quant.pt2e.qat.to_eval / set_mode."""
    from edgepick.models import ModelConfig, build_model
    from edgepick.quant.config import QuantConfig
    from edgepick.quant.pt2e.graph import prepare

    torch.manual_seed(0)
    return prepare(build_model(ModelConfig()), QuantConfig(), Size(96, 64), qat=True)


def _prepared_qat(trained_run):
    from edgepick.quant.config import QuantConfig
    from edgepick.quant.pt2e.graph import prepare
    from edgepick.train.checkpoint import load_model

    model, ckpt = load_model(trained_run)
    size = ckpt.input_size
    return prepare(model, QuantConfig(), size, qat=True), size


def test_calibrated_start_is_where_static_ptq_is(trained_run, small_data):
    """Converted right after a held calibration, the QaT graph is as close to fp32 as static PTQ is."""
    import copy

    from torchao.quantization.pt2e import disable_observer

    from edgepick.models.deeplabv3 import LogitsNet
    from edgepick.quant.config import QuantConfig
    from edgepick.quant.pt2e.graph import as_input, convert
    from edgepick.quant.pt2e.graph import prepare as prepare_graph
    from edgepick.quant.pt2e.images import model_images
    from edgepick.quant.pt2e.qat import activation_fake_quants, calibrate_activations, to_eval
    from edgepick.train.checkpoint import load_model

    prepared, size = _prepared_qat(trained_run)
    images = model_images(small_data, "train", 8, size)
    assert calibrate_activations(prepared, images, hold=True) == len(activation_fake_quants(prepared)) > 0
    fresh = copy.deepcopy(prepared)  # the calibrated start, before any training-mode pass moves BN's statistics
    ranges = {n: (float(fq.activation_post_process.min_val), float(fq.activation_post_process.max_val))
              for n, fq in activation_fake_quants(prepared).items()}
    prepared.train()
    with torch.no_grad():  # a training-mode pass: held activation ranges must not move
        prepared(torch.stack([as_input(i)[0] for i in images[:4]]))
    assert ranges == {n: (float(fq.activation_post_process.min_val), float(fq.activation_post_process.max_val))
                      for n, fq in activation_fake_quants(prepared).items()}

    to_eval(fresh)
    with torch.no_grad():  # weight ranges from one eval pass; BN statistics untouched
        fresh(as_input(images[0]))
    fresh.apply(disable_observer)
    qat_start = convert(fresh)

    model, _ = load_model(trained_run)
    static = prepare_graph(model, QuantConfig(calib_method="percentile"), size, qat=False)
    with torch.no_grad():
        for rgb in images:
            static(as_input(rgb))
    static = convert(static)
    model, _ = load_model(trained_run)
    val = model_images(small_data, "val", 8, size)
    with torch.no_grad():
        labels = {name: torch.cat([net(as_input(v)).argmax(1) for v in val])
                  for name, net in {"fp32": LogitsNet(model.eval()), "qat_start": qat_start, "static": static}.items()}
    agree = {name: float((labels[name] == labels["fp32"]).float().mean()) for name in ("qat_start", "static")}
    assert agree["qat_start"] >= agree["static"] - 0.01, agree


def test_calibration_hook_leaves_the_input_alone():
    """The calibration's pre-hook shows each input to its observer (on the CPU) without replacing it:
    an observer returns its input, and a pre-hook that returns that CPU copy moved a GPU graph's
    activations to the CPU (onto the wrong device for the next op)."""
    from edgepick.quant.pt2e.qat import _observing

    seen = []
    module = torch.nn.Identity()
    module.register_forward_pre_hook(_observing(lambda t: seen.append(t) or t))
    x = torch.arange(4, dtype=torch.float64)
    assert module(x) is x
    assert seen[0].dtype == torch.float32 and torch.equal(seen[0], x.float())


@pytest.mark.slow
@pytest.mark.parametrize("after", ["prepare", "train_switch"])
def test_qat_graph_keeps_the_models_batchnorm_eps(after):
    """torchao's QaT rewrites reset BatchNorm to eps 1e-5; MobileNetV3's is 1e-3. With fake-quant off,
    the QaT graph must compute what the float model computes, also for channels of tiny variance."""
    import torch
    from torchao.quantization.pt2e import disable_fake_quant, disable_observer

    from edgepick.models import LogitsNet, ModelConfig, build_model
    from edgepick.quant.config import QuantConfig
    from edgepick.quant.pt2e.graph import prepare
    from edgepick.quant.pt2e.qat import to_eval

    torch.manual_seed(0)
    model = build_model(ModelConfig(num_classes=4))
    bns = [m for m in model.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert {m.eps for m in bns} == {1e-3, 1e-5}  # backbone (torchvision's MobileNetV3) and head
    with torch.no_grad():
        for m in bns:  # some channels of tiny variance, where eps decides the output (3x with eps 1e-5)
            m.running_var[::3] = 1e-4
            m.weight[::3] = (1e-4 + m.eps) ** 0.5
    model.eval()
    x = torch.rand(2, 3, 64, 96) * 255
    with torch.no_grad():
        want = LogitsNet(model)(x)
    prepared = prepare(model, QuantConfig(), Size(96, 64), qat=True)
    if after == "train_switch":
        prepared.train()  # what the training loop does before its first step; nothing else is called
    prepared.apply(disable_observer)
    prepared.apply(disable_fake_quant)
    to_eval(prepared)
    with torch.no_grad():
        got = prepared(x)
    assert torch.allclose(got, want, rtol=1e-3, atol=1e-3 * float(want.abs().max())), float((got - want).abs().max())


@pytest.mark.slow
def test_weight_range_averaging_reaches_the_fake_quants():
    """--weight-averaging 1.0: each QaT step quantizes the weights with that step's own range."""
    from edgepick.models import ModelConfig, build_model
    from edgepick.quant.config import QatOptions, QuantConfig
    from edgepick.quant.pt2e.graph import prepare

    prepared = prepare(build_model(ModelConfig(num_classes=4)), QuantConfig(), Size(96, 64),
                       qat=QatOptions(weight_averaging=1.0))
    weight_fqs = [m for m in prepared.modules() if getattr(m, "is_per_channel", False)]
    assert weight_fqs and {m.activation_post_process.averaging_constant for m in weight_fqs} == {1.0}
    x = torch.rand(2, 3, 64, 96) * 255
    with torch.no_grad():
        prepared(x)
        first = [m.activation_post_process.max_val.clone() for m in weight_fqs]
        for p in prepared.parameters():
            p.mul_(2.0)  # every conv weight (and BN gamma) doubles: an exact range grows 2x (4x where BN is fused)
        prepared(x)
    grown = torch.cat([m.activation_post_process.max_val / f for m, f in zip(weight_fqs, first)])
    assert float(grown[~grown.isnan()].min()) >= 1.9  # with averaging 0.01: ~1.02x


def _with_tiny_variance_channels(model: torch.nn.Module, k: float = 0.01) -> int:
    """Scale every third channel of each conv-BN pair's conv by K, its running statistics to match and
    its gamma to compensate: the float model computes the same, but eps now decides those channels' scale.
    Returns the number of pairs changed."""
    changed = 0
    with torch.no_grad():
        for mod in model.modules():
            children = list(mod.children())
            for conv, bn in zip(children, children[1:]):
                if isinstance(conv, torch.nn.Conv2d) and isinstance(bn, torch.nn.BatchNorm2d):
                    c = slice(0, None, 3)
                    before = (bn.running_var[c] + bn.eps).sqrt()
                    conv.weight[c] *= k
                    bn.running_mean[c] *= k
                    bn.running_var[c] *= k * k
                    bn.weight[c] *= (bn.running_var[c] + bn.eps).sqrt() / (k * before)
                    changed += 1
    return changed


def test_converted_qat_graph_computes_what_qat_trained(trained_run, small_data):
    """The int8 model that convert gives must be the QaT graph that was trained: the same BN eps in the
    fold (convert_pt2e folds with 1e-5; MobileNetV3 uses 1e-3) and the same weight scales (torchao's
    fused fake-quant kernel computes its own: no eps floor, an asymmetric grid for one-signed channels)."""
    from torchao.quantization.pt2e import FakeQuantizeBase, disable_observer

    from edgepick.models.deeplabv3 import LogitsNet
    from edgepick.quant.config import QuantConfig
    from edgepick.quant.pt2e.graph import as_input, convert, prepare
    from edgepick.quant.pt2e.images import model_images
    from edgepick.quant.pt2e.qat import to_eval
    from edgepick.train.checkpoint import load_model

    model, ckpt = load_model(trained_run)
    size = ckpt.input_size
    train = torch.stack([as_input(i)[0] for i in model_images(small_data, "train", 8, size)])
    val = torch.stack([as_input(i)[0] for i in model_images(small_data, "val", 8, size)])
    model.eval()
    with torch.no_grad():
        want = LogitsNet(model)(val).argmax(1)
        assert _with_tiny_variance_channels(model) > 50
        assert float((LogitsNet(model)(val).argmax(1) == want).float().mean()) > 0.999  # the same float model
    prepared = prepare(model, QuantConfig(), size, qat=True)
    with torch.no_grad():
        prepared(train)  # a training-mode pass sets the ranges
    prepared.apply(disable_observer)
    to_eval(prepared)
    for m in prepared.modules():
        if isinstance(m, FakeQuantizeBase) and m.is_per_channel:  # trained scales == deployed scales
            scale, zero_point = m.calculate_qparams()
            assert torch.equal(m.scale, scale.to(m.scale)) and not zero_point.any()
    with torch.no_grad():
        trained = prepared(val).argmax(1)
        deployed = convert(prepared, snap_biases=False)(val).argmax(1)  # bias rounding is onnxruntime's, not QaT's
    # measured: 0.997; with the 1e-5 fold 0.68, with the fused weight kernel 0.97
    assert float((trained == deployed).float().mean()) >= 0.99


def test_no_fake_quant_learns_from_training_dropout(fresh_qat):
    """ASPP's Dropout(0.5) doubles what follows it in training only: a fake-quant there would learn a
    2x range and deploy the head conv's input at half the resolution. The conv reads the grid before it."""
    from torchao.quantization.pt2e import FakeQuantizeBase

    prepared = fresh_qat
    dropouts = [n for n in prepared.graph.nodes if n.target == torch.ops.aten.dropout.default]
    assert len(dropouts) == 1
    (drop,) = dropouts
    assert isinstance(prepared.get_submodule(drop.args[0].target), FakeQuantizeBase)  # its input is on a grid
    assert [u.target for u in drop.users] == [torch.ops.aten.conv2d.default]  # read straight by the head conv


def test_qat_state_loads_only_into_the_graph_it_came_from(fresh_qat):
    """A QaT checkpoint loads into a freshly prepared graph; an entry the graph does not have (a fake-quant
    more, or a foreign weight) is a one-line CheckpointError naming it, not silently dropped."""
    import copy

    from edgepick.errors import CheckpointError
    from edgepick.models import ModelConfig
    from edgepick.train.checkpoint import load_weights

    prepared = copy.deepcopy(fresh_qat)
    classes = ("background", "bearing", "disk", "adapter", "box")
    ckpt = Checkpoint(model_config=ModelConfig(), classes=classes, input_size=Size(96, 64), model={})
    load_weights(prepared, prepared.state_dict(), ckpt)
    for extra in ("activation_post_process_999.scale", "model.extra.weight"):
        with pytest.raises(CheckpointError, match=f"the model has no tensor {extra}"):
            load_weights(prepared, {**prepared.state_dict(), extra: torch.ones(1)}, ckpt)


@pytest.mark.slow
def test_eval_copy_is_an_exact_eval_graph(fresh_qat):
    """Validation of a QaT run uses an eval-mode copy (switching the graph costs ~1 s each way):
    after training steps and a weight copy it must give what the trained graph gives in eval mode."""
    import copy

    from torchao.quantization.pt2e import disable_observer

    from edgepick.quant.pt2e.qat import eval_copy, to_eval

    model = copy.deepcopy(fresh_qat)
    evaluator = eval_copy(model)
    x = torch.rand(4, 3, 64, 96) * 255
    opt = torch.optim.SGD(model.parameters(), 0.01)
    for _ in range(3):  # moves weights, BN running statistics and observer ranges
        model(x).mean().backward()
        opt.step()
        opt.zero_grad()
    evaluator.load_state_dict(model.state_dict())
    reference = copy.deepcopy(model)
    to_eval(reference)
    for m in (evaluator, reference):
        m.apply(disable_observer)  # eval-mode observers still update their ranges on each call
    with torch.no_grad():
        assert torch.equal(evaluator(x), reference(x))
        stale = eval_copy(copy.deepcopy(fresh_qat))
        stale(x)  # its own (untrained) ranges: a never-observed per-channel fake-quant has no scales yet
        stale.apply(disable_observer)
        assert not torch.equal(stale(x), reference(x))  # the check can fail


def test_hybrid_qat_continues_with_the_float_runs_optimizer_moments(trained_run, fresh_qat):
    """Hybrid-QaT's fake-quant graph gets the AdamW moments of the float checkpoint it starts from."""
    import copy

    from edgepick.models import ModelConfig
    from edgepick.train.loop import carry_optimizer_state

    start = Checkpoint.load(trained_run / "epoch_002.pt")
    assert start.model_config == ModelConfig()  # the graph of fresh_qat, with its own fresh weights
    model = copy.deepcopy(fresh_qat)
    opt = torch.optim.AdamW(model.parameters())
    params = dict(model.named_parameters())
    float_shapes = {k: v.shape for k, v in start.model.items()}
    # all but the dilated ASPP convs that prepare trims to the taps a 96x64 input reaches
    same_shape = sum(float_shapes[n.removeprefix("model.")] == p.shape for n, p in params.items())
    assert carry_optimizer_state(opt, model, start, prefix="model.") == same_shape > 150
    first = next(iter(start.optimizer["state"].values()))  # the float model's first parameter
    assert torch.equal(opt.state[params["model.backbone.0.0.weight"]]["exp_avg"], first["exp_avg"])
    assert float(opt.state[params["model.backbone.0.0.weight"]]["step"]) == float(first["step"]) > 0


def test_a_qat_checkpoint_loads_into_the_graph_that_trained(fresh_qat):
    """A QaT pass exports its best epoch by loading that checkpoint into the graph it trained (no second
    torch.export): every weight, BN statistic and fake-quant range of the graph is then the checkpoint's."""
    import copy

    from edgepick.models import ModelConfig
    from edgepick.quant.pt2e.qat import load_qat

    trained = copy.deepcopy(fresh_qat)
    best = fresh_qat.state_dict()  # with its version metadata, as a checkpoint keeps it (torchao's observers read it)
    for k, v in best.items():
        if v.is_floating_point():
            best[k] = v + 1  # another epoch's
    ckpt = Checkpoint(model_config=ModelConfig(), classes=tuple("abcde"), input_size=Size(96, 64), model=best)
    graph = load_qat(ckpt, trained)
    assert graph is trained
    loaded = graph.state_dict()
    assert set(loaded) == set(best)
    assert not [k for k, v in best.items() if not torch.equal(loaded[k], v)]
