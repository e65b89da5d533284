"""pved.rl: PPO (the learner of every policy in pved), policies and their evaluation.

``train_ppo(env, PPOConfig(...), run)`` trains on any :class:`pved.envs.base.BatchedEnv`
and returns a :class:`Policy`; ``load_policy(path)`` reads a saved one back;
``evaluate_policy(policy, env, episodes, seed)`` measures it.
"""

from pved.rl.evaluate import evaluate_policy
from pved.rl.losses import compute_gae, ppo_loss, ppo_loss_grad
from pved.rl.policy import Policy, load_policy
from pved.rl.ppo import PPOConfig, train_ppo

__all__ = [
    "PPOConfig",
    "Policy",
    "compute_gae",
    "evaluate_policy",
    "load_policy",
    "ppo_loss",
    "ppo_loss_grad",
    "train_ppo",
]
