"""Tests of the PVED ablations (paper IV.B) and the Gupta et al. 2017 baseline: each one's
structure is what its name says, each trains through the one registry interface, and
each round-trips through its weights file."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.distributions import Normal, kl_divergence

from pved.errors import PvedError
from pved.models import (
    MODELS,
    PVED,
    PVEDVAE,
    Gupta2017,
    Gupta2017Config,
    ModelConfig,
    ModelDims,
    PVEDConfig,
    PVEDDetShared,
    PVEDDetSharedConfig,
    PVEDSharedOnly,
    PVEDSharedOnlyConfig,
    PVEDStateOnly,
    PVEDVAEConfig,
    SharedSpaceModel,
    build_model,
    kl_diag_gaussians,
    kl_standard_normal,
    load_model,
    save_model,
    train_model,
)
from pved.models.numpy_grad import numpy_trainable
from pved.runs import Run

torch.set_num_threads(1)

NAMES = ("pved-state-only", "pved-shared-only", "pved-det-shared", "pved-vae", "gupta2017")
CLASSES = {
    "pved-state-only": PVEDStateOnly,
    "pved-shared-only": PVEDSharedOnly,
    "pved-det-shared": PVEDDetShared,
    "pved-vae": PVEDVAE,
    "gupta2017": Gupta2017,
}
# The layout of paired_rows: x_S = 4 state + 2 action entries, x_T = 3 state + 2 action.
DIMS = ModelDims(source_dim=6, target_dim=5, source_state_dim=4, target_state_dim=3)
STATE_DIMS = (4, 3)


def paired_rows(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Source rows (n, 6) and target rows (n, 5), states and actions alike nonlinear
    functions of one shared 2-d latent, plus a 1-d latent of each agent's own and a little
    noise. The maps are fixed; only the samples depend on ``seed``."""
    maps = np.random.default_rng(99)
    shared_s, shared_t = maps.normal(size=(2, 6)), maps.normal(size=(2, 5))
    own_s, own_t = maps.normal(size=(1, 6)), maps.normal(size=(1, 5))
    data = np.random.default_rng(seed)
    z = data.normal(size=(n, 2))
    x_s = np.tanh(z @ shared_s) + 0.3 * np.tanh(data.normal(size=(n, 1)) @ own_s)
    x_t = np.sin(z @ shared_t) + 0.3 * np.tanh(data.normal(size=(n, 1)) @ own_t)
    x_s += 0.05 * data.normal(size=x_s.shape)
    x_t += 0.05 * data.normal(size=x_t.shape)
    return x_s, x_t


def quick_config(name: str, **overrides: object) -> ModelConfig:
    """A few fast epochs; as in test_models_pved, a weaker α3 suits the higher lr."""
    base = MODELS[name].config_class()
    values: dict[str, object] = {"lr": 3e-3, "batch_size": 128, "epochs": 12, "seed": 0}
    if isinstance(base, PVEDConfig):
        values["alpha3"] = 1.0
    values.update(overrides)
    return dataclasses.replace(base, **values)


def fitted(
    name: str, dims: ModelDims = DIMS, config: ModelConfig | None = None
) -> SharedSpaceModel:
    """An untrained model whose standardisation is fitted to offset, scaled data, so that a
    wrong column or a forgotten standardisation changes the numbers."""
    torch.manual_seed(0)
    model = build_model(name, dims, config)
    gen = torch.Generator().manual_seed(1)
    model.fit_standardization(
        torch.randn(256, dims.source_dim, generator=gen) * 2 + 1,
        torch.randn(256, dims.target_dim, generator=gen) * 0.5 - 1,
    )
    return model


def with_new_actions(x: torch.Tensor, state_dim: int, seed: int) -> torch.Tensor:
    """``x`` with every action entry (after the first ``state_dim``) redrawn."""
    out = x.clone()
    gen = torch.Generator().manual_seed(seed)
    out[:, state_dim:] = torch.randn(out.shape[0], out.shape[1] - state_dim, generator=gen) * 3
    return out


def losses(
    model: SharedSpaceModel, x_s: torch.Tensor, x_t: torch.Tensor, seed: int = 0
) -> dict[str, torch.Tensor]:
    with torch.no_grad():
        return model.loss(x_s, x_t, torch.Generator().manual_seed(seed))


def batch(n: int = 64, seed: int = 5) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return torch.randn(n, 6, generator=gen), torch.randn(n, 5, generator=gen)


# -- registry and configs ------------------------------------------------------------------
def test_registry_has_every_model_with_its_config() -> None:
    for name, cls in CLASSES.items():
        assert MODELS[name] is cls and cls.name == name
        model = build_model(name, DIMS)
        assert type(model) is cls and model.config == cls.config_class()
        # The ablations take PVED's settings, so Table 1's α weights apply to them.
        assert isinstance(model.config, PVEDConfig) == (name != "gupta2017")
    with pytest.raises(PvedError, match=r"unknown model 'pved-nope'; known models: .*gupta2017"):
        build_model("pved-nope", DIMS)
    x_s, x_t = paired_rows(50)
    with pytest.raises(PvedError, match="unknown model"):
        train_model("gupta", x_s, x_t, state_dims=STATE_DIMS, progress=False)
    with pytest.raises(PvedError, match="needs a Gupta2017Config"):
        build_model("gupta2017", DIMS, PVEDConfig())
    with pytest.raises(PvedError, match="needs a PVEDDetSharedConfig"):
        build_model("pved-det-shared", DIMS, PVEDVAEConfig())


def test_config_validation() -> None:
    with pytest.raises(PvedError, match="weight_align must be a finite number >= 0"):
        Gupta2017Config(weight_align=-1.0)
    with pytest.raises(PvedError, match="weight_recon_source"):
        Gupta2017Config(weight_recon_source=float("nan"))
    with pytest.raises(PvedError, match="shared_dim must be >= 1"):
        Gupta2017Config(shared_dim=0)
    with pytest.raises(PvedError, match="lr must be a finite number > 0"):
        Gupta2017Config(lr=0.0)
    with pytest.raises(PvedError, match="alpha3"):
        PVEDDetSharedConfig(alpha3=-2.0)
    # Shared-only fixes y away: not a setting at all.
    assert PVEDSharedOnlyConfig().individual_dim == 0
    with pytest.raises(TypeError, match="individual_dim"):
        PVEDSharedOnlyConfig(individual_dim=10)  # type: ignore[call-arg]
    for name in ("pved-state-only", "gupta2017"):
        with pytest.raises(PvedError, match="state dim is 0"):
            build_model(name, ModelDims(6, 5, 0, 3))


def test_configs_follow_a_pairs_pved_settings() -> None:
    """The way a pair preset configures any model (copy the init fields it shares with the
    pair's PVEDConfig) works for every one, shared-only included (it has no y to take)."""
    pair = PVEDConfig(alpha1=2.5, alpha2=2.5, alpha3=15.0, lr=5e-4, batch_size=64, hidden=32)
    for name in NAMES:
        cls = MODELS[name].config_class
        own = {f.name for f in dataclasses.fields(cls) if f.init}
        config = cls(
            **{f.name: getattr(pair, f.name) for f in dataclasses.fields(pair) if f.name in own}
        )
        assert (config.lr, config.batch_size) == (5e-4, 64)
        assert isinstance(config, PVEDConfig | Gupta2017Config) and config.hidden == 32
        if isinstance(config, PVEDConfig):
            assert (config.alpha1, config.alpha2, config.alpha3) == (2.5, 2.5, 15.0)
            assert config.individual_dim == (0 if name == "pved-shared-only" else 10)
        build_model(name, DIMS, config)


# -- structure of each variant ---------------------------------------------------------------
def test_state_only_sees_no_actions() -> None:
    model = fitted("pved-state-only")
    assert isinstance(model, PVEDStateOnly)
    # Encoders read states; every decoder reconstructs a state (Eqs. 2, 6, 8 on s only).
    assert model.encoder_S.trunk[0].in_features == 4
    assert model.encoder_T.trunk[0].in_features == 3
    assert model.decoder_T.body[-1].out_features == 3
    assert model.decoder_S.body[-1].out_features == 4
    assert model.decoder_T_prime.body[-1].out_features == 4
    assert model.decoder_S_prime.body[-1].out_features == 3

    x_s, x_t = batch()
    x_s2, x_t2 = with_new_actions(x_s, 4, 1), with_new_actions(x_t, 3, 2)
    a, b = losses(model, x_s, x_t), losses(model, x_s2, x_t2)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    with torch.no_grad():
        pairs = [
            (model.shaping(x_s, x_t), model.shaping(x_s2, x_t2)),
            (model.shared_source(x_s).mean, model.shared_source(x_s2).mean),
            (model.shared_target(x_t).logvar, model.shared_target(x_t2).logvar),
            (model.predict_target(x_s), model.predict_target(x_s2)),
            (model.reconstruct_target(x_t), model.reconstruct_target(x_t2)),
        ]
        ind, ind2 = model.individual_source(x_s), model.individual_source(x_s2)
        assert ind is not None and ind2 is not None
        pairs.append((ind.mean, ind2.mean))
    for first, second in pairs:
        assert torch.equal(first, second)
    # Predictions are raw states.
    assert model.predict_target(x_s).shape == (64, 3)
    assert model.reconstruct_source(x_s).shape == (64, 4)
    # The full PVED does read actions: the check has teeth.
    full = fitted("pved")
    with torch.no_grad():
        assert not torch.equal(full.shaping(x_s, x_t), full.shaping(x_s2, x_t2))


def test_shared_only_has_no_individual_subspace() -> None:
    model = fitted("pved-shared-only")
    assert isinstance(model, PVEDSharedOnly)
    names = [n for n, _ in model.named_parameters()]
    assert not [n for n in names if "head_y" in n or "from_y" in n]
    assert any("head_y" in n for n, _ in fitted("pved").named_parameters())
    assert model.encoder_S.head_y is None and model.decoder_T.from_y is None
    # p_θT(x_T | c_T) sees c alone: 64 units into its body, not 64 + 64.
    assert model.decoder_T.body[0].in_features == model.config.hidden
    x_s, x_t = batch()
    assert model.individual_source(x_s) is None and model.individual_target(x_t) is None
    parts = losses(model, x_s, x_t)
    # The Eq. 2 prior KL is then the one on c, the same posterior as Eq. 8's.
    torch.testing.assert_close(parts["kl_ST"], parts["kl_SS"])
    torch.testing.assert_close(parts["kl_TS"], parts["kl_TT"])


def test_det_shared_is_a_point_with_euclidean_consistency_and_shaping() -> None:
    cfg = dataclasses.replace(PVEDDetSharedConfig(), alpha1=1.5, alpha2=0.5, alpha3=7.0)
    model = fitted("pved-det-shared", config=cfg)
    assert isinstance(model, PVEDDetShared)
    c_dim, y_dim = cfg.shared_dim, cfg.individual_dim
    assert model.encoder_S.head_c.out_features == c_dim  # a point, no log-variance
    assert model.encoder_S.head_y is not None
    assert model.encoder_S.head_y.out_features == 2 * y_dim  # y stays a Gaussian
    x_s, x_t = batch()
    with torch.no_grad():
        rep_s, rep_t = model.shared_source(x_s), model.shared_target(x_t)
        assert rep_s.logvar is None and rep_t.logvar is None
        assert rep_s.mean.shape == rep_t.mean.shape == (64, c_dim)
        shaping = model.shaping(x_s, x_t)
        q_y = model.individual_source(x_s)
    assert q_y is not None
    diff = rep_s.mean - rep_t.mean
    torch.testing.assert_close(shaping, diff.pow(2).sum(-1).sqrt())
    assert shaping.shape == (64,) and bool((shaping >= 0).all())

    parts = losses(model, x_s, x_t)
    # No KL on c anywhere: the c-only terms are pure log-likelihoods ...
    assert "kl_SS" not in parts and "kl_TT" not in parts
    torch.testing.assert_close(parts["L_SS"], parts["loglik_SS"])
    # ... and the Eq. 2 KL is y's alone.
    y_prior = Normal(torch.zeros(()), torch.ones(()))
    kl_y = kl_divergence(Normal(q_y.mean, (0.5 * q_y.logvar).exp()), y_prior).sum(-1).mean()
    torch.testing.assert_close(parts["kl_ST"], kl_y)
    torch.testing.assert_close(parts["L_C"], -0.5 * diff.pow(2).sum(-1).mean())
    expected = -(
        1.5 * (parts["L_ST"] + parts["L_TS"])
        + 0.5 * (parts["L_SS"] + parts["L_TT"])
        + 7.0 * parts["L_C"]
    )
    torch.testing.assert_close(parts["total"], expected)
    # c is never sampled: other noise changes only the terms that sample y.
    other = losses(model, x_s, x_t, seed=1)
    for key in ("loglik_SS", "loglik_TT", "L_C"):
        assert torch.equal(parts[key], other[key]), key
    assert not torch.equal(parts["loglik_ST"], other["loglik_ST"])


def test_vae_feeds_each_decoder_its_own_agents_posterior() -> None:
    model = fitted("pved-vae")
    assert isinstance(model, PVEDVAE)
    x_s, x_t = batch()
    gen = torch.Generator().manual_seed(7)
    x_s_moved = x_s + torch.randn(x_s.shape, generator=gen)
    x_t_moved = x_t + torch.randn(x_t.shape, generator=gen)
    base = losses(model, x_s, x_t)
    source_moved = losses(model, x_s_moved, x_t)
    target_moved = losses(model, x_s, x_t_moved)
    target_only = ("loglik_ST", "kl_ST", "loglik_TT", "kl_TT")  # p_θT and p_θ'S: x_T's own
    source_only = ("loglik_TS", "kl_TS", "loglik_SS", "kl_SS")  # p_θS and p_θ'T: x_S's own
    for key in target_only:
        assert torch.equal(base[key], source_moved[key]), key
        assert not torch.equal(base[key], target_moved[key]), key
    for key in source_only:
        assert torch.equal(base[key], target_moved[key]), key
        assert not torch.equal(base[key], source_moved[key]), key
    # Consistency still couples the two.
    assert not torch.equal(base["L_C"], source_moved["L_C"])
    assert not torch.equal(base["L_C"], target_moved["L_C"])
    # The Eq. 2 KL is that of the TARGET encoder's (c, y) posterior.
    with torch.no_grad():
        q_c, q_y = model.encode_target(x_t)
    assert q_y is not None
    torch.testing.assert_close(
        base["kl_ST"], (kl_standard_normal(*q_c) + kl_standard_normal(*q_y)).mean()
    )
    # Same networks as PVED, wired crosswise there: the check has teeth.
    pved = PVED(DIMS)
    pved.load_state_dict(model.state_dict())
    assert not torch.equal(
        losses(pved, x_s, x_t)["loglik_ST"], losses(pved, x_s_moved, x_t)["loglik_ST"]
    )
    # Shaping: the KL from the source-inferred to the target-inferred shared posterior.
    with torch.no_grad():
        rep_s, rep_t = model.shared_source(x_s), model.shared_target(x_t)
        assert rep_s.logvar is not None and rep_t.logvar is not None
        expected = kl_diag_gaussians(rep_s.mean, rep_s.logvar, rep_t.mean, rep_t.logvar)
        torch.testing.assert_close(model.shaping(x_s, x_t), expected)
        assert model.predict_target(x_s).shape == (64, 5)
        assert model.predict_source(x_t).shape == (64, 6)


def test_gupta_loss_is_its_weighted_terms_on_states_only() -> None:
    cfg = Gupta2017Config(weight_recon_source=0.3, weight_recon_target=2.0, weight_align=5.0)
    model = fitted("gupta2017", config=cfg)
    assert isinstance(model, Gupta2017)
    assert model.embed_S[0][0].in_features == 4 and model.embed_T[0][0].in_features == 3
    assert model.embed_S[-1].out_features == model.embed_T[-1].out_features == 10
    assert model.decode_S[-1].out_features == 4 and model.decode_T[-1].out_features == 3
    x_s, x_t = batch()
    parts = losses(model, x_s, x_t)
    with torch.no_grad():
        s_s = model.standardize_source(x_s)[:, :4]
        s_t = model.standardize_target(x_t)[:, :3]
        f, g = model.embed_S(s_s), model.embed_T(s_t)
        recon_s = (model.decode_S(f) - s_s).pow(2).sum(-1).mean()
        recon_t = (model.decode_T(g) - s_t).pow(2).sum(-1).mean()
        align = (f - g).pow(2).sum(-1).mean()
    torch.testing.assert_close(parts["recon_S"], recon_s)
    torch.testing.assert_close(parts["recon_T"], recon_t)
    torch.testing.assert_close(parts["align"], align)
    torch.testing.assert_close(parts["total"], 0.3 * recon_s + 2.0 * recon_t + 5.0 * align)
    with torch.no_grad():
        shaping = model.shaping(x_s, x_t)
        rep = model.shared_source(x_s)
    torch.testing.assert_close(shaping, (f - g).pow(2).sum(-1).sqrt())
    assert rep.logvar is None
    # Actions are ignored everywhere.
    x_s2, x_t2 = with_new_actions(x_s, 4, 3), with_new_actions(x_t, 3, 4)
    moved = losses(model, x_s2, x_t2)
    assert all(torch.equal(parts[k], moved[k]) for k in parts)
    with torch.no_grad():
        assert torch.equal(model.shaping(x_s2, x_t2), shaping)


@pytest.mark.parametrize("name", NAMES)
def test_gradients_reach_every_parameter(name: str) -> None:
    model = fitted(name)
    x_s, x_t = batch(32)
    model.loss(x_s, x_t)["total"].backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.any()]
    assert not missing


@pytest.mark.parametrize("name", NAMES)
def test_bad_inputs_raise_pved_error(name: str) -> None:
    model = build_model(name, DIMS)
    with pytest.raises(PvedError, match="batches differ"):
        model.shaping(torch.randn(3, 6), torch.randn(2, 5))
    with pytest.raises(PvedError, match="batches differ"):
        model.loss(torch.randn(3, 6), torch.randn(2, 5))
    with pytest.raises(PvedError, match=r"target input must have shape \(B, 5\)"):
        model.shaping(torch.randn(3, 6), torch.randn(3, 6))


# -- training and files --------------------------------------------------------------------
@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[SharedSpaceModel, list]]:
    """Every model trained a few epochs through the registry, with its per-epoch metrics."""
    x_s, x_t = paired_rows(1200)
    root = tmp_path_factory.mktemp("runs")
    out = {}
    for name in NAMES:
        run = Run(root / name, {"model": name}, tensorboard=False)
        model = train_model(
            name, x_s, x_t, quick_config(name), run, state_dims=STATE_DIMS, progress=False
        )
        out[name] = (model, run.read_metrics())
    return out


@pytest.mark.parametrize("name", NAMES)
def test_training_learns_a_shared_space(name: str, trained: dict) -> None:
    model, records = trained[name]
    assert type(model) is CLASSES[name] and not model.training
    assert records[-1]["train/total"] < records[0]["train/total"]
    assert records[-1]["val/total"] < records[0]["val/total"]
    x_s, x_t = paired_rows(1000, seed=3)
    shuffled = x_t[np.random.default_rng(0).permutation(len(x_t))]
    xs = torch.as_tensor(x_s, dtype=torch.float32)
    with torch.no_grad():
        true = model.shaping(xs, torch.as_tensor(x_t, dtype=torch.float32))
        wrong = model.shaping(xs, torch.as_tensor(shuffled, dtype=torch.float32))
    assert true.shape == (1000,) and bool(torch.isfinite(true).all())
    assert bool((true >= 0).all()) and bool((wrong >= 0).all())
    # The shaping distance tells a time-matched pair from a random one.
    assert float(true.mean()) < 0.5 * float(wrong.mean()), (true.mean(), wrong.mean())


@pytest.mark.parametrize("name", NAMES)
def test_save_load_round_trip(name: str, trained: dict, tmp_path: Path) -> None:
    model, _ = trained[name]
    path = save_model(model, tmp_path / f"{name}.pt", {"pair": "synthetic"})
    assert torch.load(path, weights_only=True)["name"] == name
    loaded = load_model(path, expected_dims=model.dims)
    assert type(loaded) is CLASSES[name] and loaded.config == model.config
    backend = "numpy" if numpy_trainable(model) else "torch"  # recorded by training
    assert loaded.metadata == {"pair": "synthetic", "train_backend": backend}
    x_s, x_t = paired_rows(64, seed=4)
    xs, xt = torch.as_tensor(x_s, dtype=torch.float32), torch.as_tensor(x_t, dtype=torch.float32)
    with torch.no_grad():
        assert torch.equal(loaded.shaping(xs, xt), model.shaping(xs, xt))
        assert torch.equal(loaded.shared_target(xt).mean, model.shared_target(xt).mean)
    a, b = losses(loaded, xs, xt, seed=2), losses(model, xs, xt, seed=2)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    # A header naming another model than the weights fit is refused with a message.
    payload = torch.load(path, weights_only=True)
    payload["name"] = "gupta2017" if name != "gupta2017" else "pved"
    payload["config"] = {}
    tampered = tmp_path / "tampered.pt"
    torch.save(payload, tampered)
    with pytest.raises(PvedError, match="weights do not fit model"):
        load_model(tampered)
