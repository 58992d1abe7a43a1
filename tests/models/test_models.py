"""Model tier: the paper's architecture table, fusion contracts, the symmetry prior."""

from __future__ import annotations

import pytest
import torch

from tests.conftest import compose_config
from vitac.models import encoders
from vitac.models.encoders import ConvSoftArgmaxEncoder, SpatialSoftArgmax
from vitac.models.fusion import CrossModalTransformer, GatedFusion, NaiveFusion
from vitac.models.head import RecurrentActorHead
from vitac.models.symmetry import SymmetryRegularizer, flip_vertical, mirror_pad
from vitac.run_config import build_policy_from_config, task_settings
from vitac.tasks.insertion.config import InsertionConfig


def _intermediate_shapes(encoder, x):
    shapes = []
    for layer in encoder.conv:
        x = layer(x)
        if isinstance(layer, torch.nn.Conv2d):
            shapes.append(tuple(x.shape))
    return shapes


def test_vision_encoder_matches_architecture_table():
    enc = ConvSoftArgmaxEncoder((3, 64, 64))
    shapes = _intermediate_shapes(enc, torch.zeros(5, 3, 64, 64))
    assert shapes == [(5, 32, 29, 29), (5, 64, 26, 26), (5, 64, 24, 24)]
    assert tuple(enc(torch.zeros(5, 3, 64, 64)).shape) == (5, 128)


def test_tactile_encoder_matches_architecture_table():
    enc = ConvSoftArgmaxEncoder((3, 32, 32))
    shapes = _intermediate_shapes(enc, torch.zeros(5, 3, 32, 32))
    assert shapes == [(5, 32, 13, 13), (5, 64, 10, 10), (5, 64, 8, 8)]
    assert tuple(enc(torch.zeros(5, 3, 32, 32)).shape) == (5, 128)


@pytest.mark.parametrize("bf16", [False, True])
def test_bf16_encoder_runs_its_convolutions_in_bfloat16_and_stays_close_to_float32(bf16):
    torch.manual_seed(0)
    reference = ConvSoftArgmaxEncoder((3, 32, 32))
    enc = ConvSoftArgmaxEncoder((3, 32, 32), bf16=bf16)
    enc.load_state_dict(reference.state_dict())
    dtypes = []
    enc.conv[-1].register_forward_hook(lambda module, inputs, output: dtypes.append(output.dtype))
    x = torch.rand(32, 3, 32, 32)
    out = enc(x)
    assert dtypes == [torch.bfloat16 if bf16 else torch.float32]
    assert out.dtype == torch.float32 and out.shape == (32, 128)
    assert torch.allclose(out, reference(x), atol=1e-3)
    # The rollout encodes small batches and the update large ones: the same sample must give the same features.
    assert torch.allclose(torch.cat([enc(x[i:i + 8]) for i in range(0, 32, 8)]), out, atol=1e-6)
    out.sum().backward()
    assert enc.conv[0].weight.grad is not None and enc.conv[0].weight.grad.dtype == torch.float32


@pytest.mark.parametrize("extensions,expected", [([], torch.float32), (["avx512_bf16"], torch.bfloat16),
                                                 (["amx_bf16"], torch.bfloat16)])
def test_auto_bf16_follows_the_cpus_native_bfloat16(monkeypatch, extensions, expected):
    # Emulated bfloat16 convolutions ran ten times slower than float32 on an AVX2-only CPU: auto must not pick them.
    monkeypatch.setattr(encoders, "describe_cpu", lambda: dict(model="test", cores=2, bfloat16=extensions))
    encoders.native_bfloat16.cache_clear()
    try:
        enc = ConvSoftArgmaxEncoder((3, 32, 32), bf16="auto")
        dtypes = []
        enc.conv[-1].register_forward_hook(lambda module, inputs, output: dtypes.append(output.dtype))
        enc(torch.rand(2, 3, 32, 32))
        assert dtypes == [expected]
    finally:
        encoders.native_bfloat16.cache_clear()


def test_spatial_softargmax_finds_the_peak():
    x = torch.full((1, 1, 9, 9), -50.0)
    x[0, 0, 2, 6] = 50.0  # row 2 (y), column 6 (x)
    out = SpatialSoftArgmax(9, 9)(x)
    expected_x, expected_y = -1 + 2 * 6 / 8, -1 + 2 * 2 / 8
    assert torch.allclose(out, torch.tensor([[expected_x, expected_y]]), atol=1e-4)


def test_fusion_output_sizes():
    v, left, right = torch.randn(4, 128), torch.randn(4, 128), torch.randn(4, 128)
    assert NaiveFusion(128, 3)(dict(vision=v, left=left, right=right)).shape == (4, 384)
    gated = GatedFusion(128)
    assert gated(dict(vision=v, left=left, right=right)).shape == (4, 128)
    assert torch.allclose(gated.last_weights.sum(-1), torch.ones(4))
    assert CrossModalTransformer(128, num_heads=4)(dict(vision=v, left=left, right=right)).shape == (4, 256)


def test_gated_fusion_is_a_convex_combination():
    gated = GatedFusion(8)
    v, left, right = torch.ones(2, 8), 2 * torch.ones(2, 8), 3 * torch.ones(2, 8)
    out = gated(dict(vision=v, left=left, right=right))
    w = gated.last_weights
    assert torch.allclose(out, (w[:, 0:1] * 1 + w[:, 1:2] * 2 + w[:, 2:3] * 3).expand(-1, 8))


def test_cmt_vision_attends_to_tactile():
    torch.manual_seed(0)
    cmt = CrossModalTransformer(16, num_heads=2)
    v, left, right = torch.randn(1, 16), torch.randn(1, 16), torch.randn(1, 16)
    base = cmt(dict(vision=v, left=left, right=right))
    assert not torch.allclose(base, cmt(dict(vision=v, left=left + 1.0, right=right))), "tactile keys/values must influence the output"
    assert not torch.allclose(cmt(dict(vision=v, left=left, right=right)), cmt(dict(vision=v, left=right, right=left))), "left and right tokens must be distinguishable"


@pytest.mark.parametrize("mirror,transform", [("physical", mirror_pad), ("image", flip_vertical)])
def test_symmetry_loss_is_zero_for_a_mirrored_pair_and_positive_otherwise(mirror, transform):
    torch.manual_seed(0)
    enc = ConvSoftArgmaxEncoder((3, 32, 32))
    left = torch.rand(3, 3, 32, 32)
    right = transform(left)  # the right pad's view of the mirror-symmetric grasp (both transforms are involutions)
    reg = SymmetryRegularizer(mirror=mirror)
    assert torch.allclose(reg.per_sample(enc(left), enc, right), torch.zeros(3), atol=1e-10)
    assert (reg.per_sample(enc(left), enc, left.flip(-1)) > 0).all()
    with pytest.raises(ValueError, match=r"reg\.mirror='flip' is not allowed: expected one of \['physical', 'image'\]"):
        SymmetryRegularizer(mirror="flip")


def test_symmetry_after_self_attention_is_zero_for_a_scene_equal_to_its_mirror_image_and_trains_the_attention():
    torch.manual_seed(0)
    enc = ConvSoftArgmaxEncoder((3, 32, 32))
    cmt = CrossModalTransformer(enc.out_dim, num_heads=2)
    reg = SymmetryRegularizer(placement="self_attention")
    left = torch.rand(3, 3, 32, 32)

    def loss(right):
        return reg.per_sample_attended(cmt, (enc, enc), (left, right), (enc(left), enc(right)))

    assert torch.allclose(loss(mirror_pad(left)), torch.zeros(3), atol=1e-10)  # the mirror image is the same scene
    asymmetric = loss(torch.rand(3, 3, 32, 32))
    assert (asymmetric > 0).all()
    asymmetric.sum().backward()
    assert cmt.self_attn.in_proj_weight.grad.abs().sum() > 0 and cmt.side.grad.abs().sum() > 0
    assert cmt.cross_attn.in_proj_weight.grad is None  # the loss reads the tactile tokens, before vision attends
    with pytest.raises(ValueError, match=r"reg\.placement='fused' is not allowed: expected one of \['encoder', 'self_attention'\]"):
        SymmetryRegularizer(placement="fused")


def test_sigmoid_log_std_bound_starts_at_init_and_keeps_a_gradient_past_the_bound():
    head = RecurrentActorHead(4, log_std_min=-2.0, log_std_max=0.5, log_std_init=-0.3, log_std_bound="sigmoid")
    _, log_std, _, _ = head(torch.zeros(2, 1, 4), head.initial_state(1), torch.zeros(2, 1))
    assert torch.allclose(log_std, torch.full_like(log_std, -0.3), atol=1e-6)
    clamped = RecurrentActorHead(4, log_std_min=-2.0, log_std_max=0.5)
    for h in (head, clamped):
        with torch.no_grad():
            h.log_std.bias.fill_(3.0)  # past the maximum
        _, log_std, _, _ = h(torch.zeros(2, 1, 4), h.initial_state(1), torch.zeros(2, 1))
        log_std.sum().backward()
    assert head.log_std.bias.grad.abs().min() > 0 and clamped.log_std.bias.grad.abs().max() == 0
    assert float(head(torch.zeros(1, 1, 4), head.initial_state(1), torch.zeros(1, 1))[1].max().detach()) < 0.5
    with pytest.raises(ValueError, match="log_std_bound"):
        RecurrentActorHead(4, log_std_bound="tanh")


def test_log_std_is_clamped():
    head = RecurrentActorHead(4, log_std_min=-2.0, log_std_max=0.5)
    with torch.no_grad():
        head.log_std.bias.fill_(10.0)
    _, log_std, _, _ = head(torch.zeros(2, 1, 4), head.initial_state(1), torch.zeros(2, 1))
    assert torch.all(log_std == 0.5)


def _policy(reg):
    cfg = compose_config(["obs=wrist_tactile", "fusion=cmt", f"reg={reg}"])
    return build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))


def _batch(T=2, B=2):
    return {"proprio": torch.randn(T, B, 19), "wrist": torch.randint(0, 255, (T, B, 3, 64, 64), dtype=torch.uint8),
            "tactile_left": torch.rand(T, B, 3, 32, 32), "tactile_right": torch.rand(T, B, 3, 32, 32),
            "critic_state": torch.randn(T, B, 42)}


def test_symmetry_term_sends_gradient_to_the_tactile_encoders():
    torch.manual_seed(0)
    policy = _policy("sym")
    *_, sym = policy(_batch(), policy.initial_state(2), torch.zeros(2, 2), with_aux=True)
    sym.mean().backward()
    for key in ("tactile_left", "tactile_right"):
        grad = policy.encoders[key].conv[0].weight.grad
        assert grad is not None and grad.abs().sum() > 0
    assert policy.encoders["wrist"].conv[0].weight.grad is None


def test_no_symmetry_term_without_the_regularizer():
    policy = _policy("none")
    *_, sym = policy(_batch(), policy.initial_state(2), torch.zeros(2, 2), with_aux=True)
    assert sym is None and not policy.uses_symmetry


def test_one_step_lstm_path_matches_the_sequence_path():
    torch.manual_seed(0)
    head = RecurrentActorHead(10)
    x, starts = torch.randn(3, 4, 10), torch.zeros(3, 4)
    starts[1, 2] = 1.0
    seq_mean, _, seq_value, seq_state = head(x, head.initial_state(4), starts)
    state, means, values = head.initial_state(4), [], []
    for t in range(3):
        mean, _, value, state = head(x[t:t + 1], state, starts[t:t + 1])
        means.append(mean)
        values.append(value)
    assert torch.allclose(torch.cat(means), seq_mean, atol=1e-6)
    assert torch.allclose(torch.cat(values), seq_value, atol=1e-6)
    assert torch.allclose(state[0], seq_state[0], atol=1e-6) and torch.allclose(state[1], seq_state[1], atol=1e-6)


@pytest.mark.parametrize("mode", ["param", "fixed"])
def test_state_independent_log_std_is_the_same_for_every_input_and_trained_only_in_param_mode(mode):
    head = RecurrentActorHead(4, log_std_init=-1.0, log_std_mode=mode)
    features = torch.randn(3, 2, 4)
    _, log_std, _, _ = head(features, head.initial_state(2), torch.zeros(3, 2))
    assert log_std.shape == (3, 2, 6) and torch.allclose(log_std, torch.full_like(log_std, -1.0))
    trained = {name for name, _ in head.named_parameters()}
    assert ("log_std" in trained) == (mode == "param")
    assert "log_std" in head.state_dict()  # saved either way, so checkpoints rebuild the same policy
    if mode == "param":
        log_std.sum().backward()
        assert torch.all(head.log_std.grad == 3 * 2)
    with pytest.raises(ValueError, match="log_std_mode"):
        RecurrentActorHead(4, log_std_mode="learned")


def test_force_fields_reach_the_encoders_on_one_unit_scale_shared_by_both_pads():
    from vitac.models.normalizer import ForceFieldScale

    torch.manual_seed(0)
    policy = _policy("sym")
    assert policy.force_field_keys == ["tactile_left", "tactile_right"]
    field = torch.rand(4, 3, 32, 32) * 0.01
    torch.testing.assert_close(policy.force_scale(field), field)  # the identity before any statistics
    # Grasp-sized forces (newtons per taxel, about 1e-3 to 3e-2), one scale per component
    scales = torch.tensor([0.002, 0.0005, 0.03])[:, None, None]
    left, right = torch.randn(64, 3, 32, 32) * scales, torch.randn(64, 3, 32, 32) * scales
    batch = {"proprio": torch.randn(64, 19), "critic_state": torch.randn(64, 42), "tactile_left": left,
             "tactile_right": right}
    policy.update_normalizers(batch)
    scaled = policy.force_scale(torch.cat([left, right]))
    rms = scaled.square().mean(dim=(0, 2, 3)).sqrt()
    torch.testing.assert_close(rms, torch.ones(3), atol=0.02, rtol=0)
    # No centering: zero force stays zero, and the mirrored field scales as the field
    assert policy.force_scale(torch.zeros(1, 3, 32, 32)).abs().max() == 0
    torch.testing.assert_close(policy.force_scale(mirror_pad(left)), mirror_pad(policy.force_scale(left)))
    with pytest.raises(FloatingPointError, match="tactile_left"):
        policy.update_normalizers(dict(batch, tactile_left=left.masked_fill(left > 0.01, float("nan"))))
    # the statistics travel with the checkpoint
    assert {"force_scale.mean_square", "force_scale.count"} <= set(policy.state_dict())
    assert ForceFieldScale(3).mean_square.tolist() == [1.0, 1.0, 1.0]
