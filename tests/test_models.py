"""CompenNet: official layout and parameter counts, output range, input checks, surface broadcast."""
from __future__ import annotations

import math

import pytest
import torch

from compensation.methods.compennet import CompenNet, count_parameters

N, H, W = 3, 16, 24  # non-square, so swapped axes would show


def seeded(surface: bool = True, seed: int = 0) -> CompenNet:
    torch.manual_seed(seed)
    return CompenNet(surface=surface).eval()


@pytest.fixture(scope="module")
def images():
    g = torch.Generator().manual_seed(1)
    return torch.rand(N, 3, H, W, generator=g), torch.rand(1, 3, H, W, generator=g)


@pytest.mark.parametrize(("surface", "count"), [(True, 1_124_479), (False, 736_063)])
def test_parameter_counts(surface, count):
    assert count_parameters(CompenNet(surface=surface)) == count


def test_state_dict_names_follow_official_code():
    keys = set(CompenNet(surface=True).state_dict())
    layers = {k.rsplit(".", 1)[0] for k in keys}
    assert layers == {"conv1", "conv2", "conv3", "conv4", "conv5", "conv6", "transConv1",
                      "transConv2", "conv1_s", "conv2_s", "conv3_s", "conv4_s", "skipConv1.0",
                      "skipConv1.2", "skipConv1.4", "skipConv2", "skipConv3"}
    plain = set(CompenNet(surface=False).state_dict())
    assert plain == {k for k in keys if "_s." not in k}
    model = CompenNet()
    assert model.transConv1.weight.shape == (128, 64, 2, 2)  # 2×2 kernel, stride 2 (official layout)
    assert model.skipConv3.weight.shape == (128, 64, 1, 1)


def test_kaiming_normal_on_conv2d_only():
    model = seeded()
    w = model.conv4.weight  # 295k weights: the sample std is within 1% of sqrt(2 / fan_in)
    assert w.std().item() == pytest.approx(math.sqrt(2 / (128 * 9)), rel=0.01)
    assert w.mean().abs().item() < 0.01 * w.std().item()
    # Transposed convs keep PyTorch's default uniform init, bounded by 1 / sqrt(fan_in).
    t = model.transConv1.weight
    assert t.abs().max().item() <= 1 / math.sqrt(64 * 4) + 1e-7


def official_initial_state(seed: int) -> dict[str, torch.Tensor]:
    """The initial weights of the official CompenNet class for ``seed``, built as its constructor
    builds them: the layers created in its order (backbone conv1-conv5, surface branch
    conv1_s-conv4_s, transConv1, transConv2, conv6, skipConv1's three convolutions, skipConv2,
    skipConv3), each drawing PyTorch's default initialisation, then Kaiming-normal weights for every
    Conv2d (not ConvTranspose2d) in module order."""
    torch.manual_seed(seed)
    layers = {}
    for name, shape in (("conv1", (3, 32, 3, 2, 1)), ("conv2", (32, 64, 3, 2, 1)),
                        ("conv3", (64, 128, 3, 1, 1)), ("conv4", (128, 256, 3, 1, 1)),
                        ("conv5", (256, 128, 3, 1, 1)), ("conv1_s", (3, 32, 3, 2, 1)),
                        ("conv2_s", (32, 64, 3, 2, 1)), ("conv3_s", (64, 128, 3, 1, 1)),
                        ("conv4_s", (128, 256, 3, 1, 1))):
        layers[name] = torch.nn.Conv2d(*shape)
    layers["transConv1"] = torch.nn.ConvTranspose2d(128, 64, 2, 2, 0)
    layers["transConv2"] = torch.nn.ConvTranspose2d(64, 32, 2, 2, 0)
    layers["conv6"] = torch.nn.Conv2d(32, 3, 3, 1, 1)
    for i in (0, 2, 4):
        layers[f"skipConv1.{i}"] = torch.nn.Conv2d(3, 3, 3, 1, 1)
    layers["skipConv2"] = torch.nn.Conv2d(32, 64, 1, 1, 0)
    layers["skipConv3"] = torch.nn.Conv2d(64, 128, 1, 1, 0)
    for layer in layers.values():
        if type(layer) is torch.nn.Conv2d:
            torch.nn.init.kaiming_normal_(layer.weight)
    return {f"{name}.{k}": v for name, layer in layers.items() for k, v in layer.state_dict().items()}


@pytest.mark.parametrize("seed", [0, 7])
def test_seed_gives_the_official_initial_weights(seed):
    ours, official = seeded(seed=seed).state_dict(), official_initial_state(seed)
    assert ours.keys() == official.keys()
    assert all(torch.equal(ours[k], official[k]) for k in official)


def test_init_is_deterministic_under_manual_seed():
    a, b, c = seeded(seed=0).state_dict(), seeded(seed=0).state_dict(), seeded(seed=1).state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(a["conv1.weight"], c["conv1.weight"])


@pytest.mark.parametrize("surface", [True, False])
def test_output_shape_and_range(images, surface):
    x, s = images
    model = seeded(surface)
    with torch.no_grad():
        out = model(x, s)
        assert out.shape == (N, 3, H, W) and out.dtype == torch.float32
        assert 0 <= out.min().item() and out.max().item() <= 1
        # The last layer is clamp(relu(conv6 + res1), max=1): saturate it both ways.
        model.conv6.bias.fill_(100.0)
        assert torch.equal(model(x, s), torch.ones(N, 3, H, W))
        model.conv6.bias.fill_(-100.0)
        assert torch.equal(model(x, s), torch.zeros(N, 3, H, W))


@pytest.mark.parametrize(("shape", "match"), [
    ((1, 3, 30, 32), "multiples of 4, got 30x32"),
    ((1, 3, 32, 30), "multiples of 4, got 32x30"),
    ((1, 2, 32, 32), "3 channels, got 2"),
    ((3, 32, 32), r"\(N, 3, H, W\), got \(3, 32, 32\)"),
])
def test_bad_input_shapes(shape, match):
    model = CompenNet(surface=False)
    with pytest.raises(ValueError, match=match):
        model(torch.rand(shape))


def test_bad_surface_inputs(images):
    x, s = images
    model = seeded()
    with pytest.raises(ValueError, match="exactly one of the surface image s"):
        model(x)
    with pytest.raises(ValueError, match="exactly one of the surface image s"):
        model(x, s, features=model.surface_features(s))
    with pytest.raises(ValueError, match=r"expected \(1, 3, 16, 24\) or \(3, 3, 16, 24\)"):
        model(x, torch.rand(1, 3, 16, 16))
    with pytest.raises(ValueError, match=r"expected \(1, 3, 16, 24\) or \(3, 3, 16, 24\)"):
        model(x, s.expand(2, -1, -1, -1))
    with pytest.raises(ValueError, match="surface s must be RGB"):
        model(x, s[:, :1])
    with pytest.raises(ValueError, match="features must be surface_features"):
        model(x, features=model.surface_features(torch.rand(1, 3, 16, 16)))
    with pytest.raises(ValueError, match="no surface branch"):
        CompenNet(surface=False).surface_features(s)


def test_surface_of_batch_one_is_broadcast(images):
    x, s = images
    model = seeded()
    with torch.no_grad():
        shared = model(x, s)
        expanded = model(x, s.expand(N, -1, -1, -1))
        per_sample = torch.cat([model(x[i:i + 1], s) for i in range(N)])
    torch.testing.assert_close(shared, expanded, rtol=0, atol=1e-6)
    torch.testing.assert_close(shared, per_sample, rtol=0, atol=1e-6)


def test_per_sample_surfaces(images):
    x, s = images
    model = seeded()
    surfaces = torch.cat([s, s.flip(-1), 0.5 * s])
    with torch.no_grad():
        out = model(x, surfaces)
        one_by_one = torch.cat([model(x[i:i + 1], surfaces[i:i + 1]) for i in range(N)])
        other_surface = model(x[:1], surfaces[1:2])
    torch.testing.assert_close(out, one_by_one, rtol=0, atol=1e-6)
    assert not torch.allclose(out[:1], other_surface, atol=1e-3)  # the surface matters


def test_cached_features_give_identical_output(images):
    x, s = images
    model = seeded()
    with torch.no_grad():
        features = model.surface_features(s)
        assert [f.shape for f in features] == [(1, 32, 8, 12), (1, 64, 4, 6), (1, 128, 4, 6),
                                               (1, 256, 4, 6)]
        assert torch.equal(model(x, features=features), model(x, s))
        # The same cache serves batches of another size (e.g. the remainder at inference).
        assert torch.equal(model(x[:2], features=features), model(x[:2], s))


def test_without_surface_branch_ignores_s(images):
    x, s = images
    model = seeded(surface=False)
    with torch.no_grad():
        assert torch.equal(model(x, s), model(x))


def test_gradients_reach_both_branches_through_broadcast_surface(images):
    x, s = images
    model = seeded().train()
    model(x, s).mean().backward()
    for name in ("conv1", "conv1_s", "conv4_s", "transConv2", "skipConv1.0"):
        grad = model.get_submodule(name).weight.grad
        assert grad is not None and grad.abs().sum() > 0, name


@pytest.mark.parametrize("layout", [torch.contiguous_format, torch.channels_last])
def test_broadcast_surface_gradients_equal_per_sample_ones(images, layout):
    # the surface terms' gradient is summed over the batch by sum_over_batch, not by autograd
    x, s = (t.contiguous(memory_format=layout) for t in images)
    grads = []
    for surface in (s, s.expand(N, -1, -1, -1).contiguous(memory_format=layout)):
        model = seeded().to(memory_format=layout).train()
        model(x, surface).square().mean().backward()
        grads.append({n: p.grad for n, p in model.named_parameters()})
    for name, grad in grads[0].items():
        torch.testing.assert_close(grad, grads[1][name], rtol=1e-4, atol=1e-7, msg=name)
    assert grads[0]["conv4_s.weight"].abs().sum() > 0
