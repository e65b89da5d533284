"""pved.models: shared-space models of paired source/target state-actions.

The PVED model (paper III.C, Eqs. 1–10), its four ablations (paper IV.B:
``pved-state-only``, ``pved-shared-only``, ``pved-det-shared``, ``pved-vae``) and the
Gupta et al. 2017 baseline (``gupta2017``), all behind one interface
(:class:`SharedSpaceModel`); training, evaluation, and weights files::

    from pved.models import PVEDConfig, train_model, save_model, load_model
    model = train_model("pved", x_source, x_target, PVEDConfig(epochs=50),
                        state_dims=(n_state_source, n_state_target))
    save_model(model, "model.pt", {"pair": "reacher"})
    reward_term = -beta * load_model("model.pt").shaping(x_S, x_T)   # Eq. 10
"""

from pved.models.base import (
    ModelConfig,
    ModelDims,
    SharedRep,
    SharedSpaceModel,
    Standardizer,
    config_from_dict,
    config_to_dict,
)
from pved.models.distributions import (
    DiagGaussian,
    gaussian_log_likelihood,
    kl_diag_gaussians,
    kl_standard_normal,
    reparameterize,
)
from pved.models.gupta import Gupta2017, Gupta2017Config
from pved.models.pved import OBJECTIVE_TERMS, PVED, PVEDConfig
from pved.models.registry import MODELS, build_model, load_model, model_class, save_model
from pved.models.train import evaluate_model, train_model
from pved.models.variants import (
    PVEDVAE,
    PVEDDetShared,
    PVEDDetSharedConfig,
    PVEDSharedOnly,
    PVEDSharedOnlyConfig,
    PVEDStateOnly,
    PVEDStateOnlyConfig,
    PVEDVAEConfig,
)

__all__ = [
    "MODELS",
    "OBJECTIVE_TERMS",
    "PVED",
    "PVEDVAE",
    "DiagGaussian",
    "Gupta2017",
    "Gupta2017Config",
    "ModelConfig",
    "ModelDims",
    "PVEDConfig",
    "PVEDDetShared",
    "PVEDDetSharedConfig",
    "PVEDSharedOnly",
    "PVEDSharedOnlyConfig",
    "PVEDStateOnly",
    "PVEDStateOnlyConfig",
    "PVEDVAEConfig",
    "SharedRep",
    "SharedSpaceModel",
    "Standardizer",
    "build_model",
    "config_from_dict",
    "config_to_dict",
    "evaluate_model",
    "gaussian_log_likelihood",
    "kl_diag_gaussians",
    "kl_standard_normal",
    "load_model",
    "model_class",
    "reparameterize",
    "save_model",
    "train_model",
]
