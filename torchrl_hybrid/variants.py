"""The agent variants (the paper's agent, its baselines, the oracle diagnostic) and the loss
factory that builds each one from TorchRL's A2C or PPO loss and this project's losses."""

from __future__ import annotations

from dataclasses import dataclass

from torchrl.objectives import A2CLoss, ClipPPOLoss, ValueEstimators

from torchrl_hybrid.modules.inverse_dynamics import InverseDynamicsModel
from torchrl_hybrid.objectives import (
    DualInverseDynamicsLoss,
    ExpertBCLoss,
    HybridLoss,
    InverseDynamicsLoss,
    PolicyEntropyLoss,
)

__all__ = ["RL_BASES", "VARIANTS", "Variant", "get_variant", "make_hybrid_loss", "param_groups"]


@dataclass(frozen=True)
class Variant:
    """What an agent variant switches on.

    Attributes:
        rl: train with the A2C loss; without it the policy still gets the
            entropy bonus (the authors' BC baselines are the hybrid agent with
            policy-gradient and value weights 0).
        bc: ``"inferred"`` (clone actions inferred by the inverse model),
            ``"true"`` (clone the true expert actions: IL) or ``None``.
        inverse_model: ``"dual"``, ``"mlp"`` or ``None``.
    """

    name: str
    rl: bool
    bc: str | None
    inverse_model: str | None
    description: str


#: the RL loss of the variants that have one: the paper's A2C, or PPO (TorchRL's ClipPPOLoss with GAE)
RL_BASES = ("a2c", "ppo")

VARIANTS: dict[str, Variant] = {
    v.name: v
    for v in (
        Variant(
            "hybrid_dual",
            True,
            "inferred",
            "dual",
            "A2C + BC on actions inferred by the dual model (the paper's agent)",
        ),
        Variant("hybrid_mlp", True, "inferred", "mlp", "A2C + BC on actions inferred by the MLP inverse model"),
        Variant("bc_dual", False, "inferred", "dual", "BC on actions inferred by the dual model, no RL signal"),
        Variant("bc_mlp", False, "inferred", "mlp", "BC on actions inferred by the MLP model, no RL signal"),
        Variant("il", False, "true", None, "BC on the TRUE expert actions (imitation learning upper bound)"),
        # a diagnostic, never a way to train with real demos: the demos keep the expert's true actions
        # only so that this arm can show how much any inverse model could give (oracle labels)
        Variant(
            "hybrid_true",
            True,
            "true",
            None,
            "DIAGNOSTIC: A2C + BC on the expert's TRUE actions, the upper bound of any inverse model's labels",
        ),
        Variant("a2c", True, None, None, "plain A2C, ignores the demonstrations"),
    )
}


def get_variant(name: str) -> Variant:
    if name not in VARIANTS:
        raise ValueError(f"unknown variant {name!r}; choose one of: {', '.join(VARIANTS)}")
    return VARIANTS[name]


def make_hybrid_loss(
    variant: Variant,
    actor,
    critic,
    inverse_model: InverseDynamicsModel | None,
    *,
    gamma: float = 0.99,
    critic_coeff: float = 0.2,
    entropy_coeff: float = 0.5,
    idm_action_coeff: float = 2.0,
    idm_embedding_coeff: float = 0.1,
    idm_forward_coeff: float = 0.0,
    bc_coeff: float = 2.0,
    bc_labels: str = "argmax",
    bc_confidence: float = 0.0,
    bc_entropy_floor: float = 0.0,
    bc_prior_floor: float = 0.0,
    expert_action_key: str = "expert_action",
    value_estimator_kwargs: dict | None = None,
    rl: str = "a2c",
    ppo: dict | None = None,
) -> HybridLoss:
    """Builds the variant's :class:`HybridLoss`.

    The RL part (``rl="a2c"``, the paper's) is TorchRL's ``A2CLoss`` with the n-step
    return of each rollout (TD(1) over the rollout, bootstrapped from the critic at its
    end), an L2 critic loss weighted ``critic_coeff`` and an entropy bonus
    ``entropy_coeff``; ``rl="ppo"`` is TorchRL's ``ClipPPOLoss`` with GAE (``ppo``:
    ``clip_epsilon``, ``gae_lambda``, ``normalize_advantage``), its epochs and minibatches
    run by a :class:`~torchrl_hybrid.trainers.hooks.MinibatchHook`.
    """
    if (variant.inverse_model is None) != (inverse_model is None):
        raise ValueError(f"variant {variant.name!r} {'needs' if variant.inverse_model else 'takes no'} inverse model")
    if rl not in RL_BASES:
        raise ValueError(f"rl={rl!r}: choose one of {RL_BASES}")
    rl_loss = None
    if variant.rl and rl == "ppo":
        ppo = {"clip_epsilon": 0.2, "gae_lambda": 0.95, "normalize_advantage": True, **(ppo or {})}
        rl_loss = ClipPPOLoss(
            actor,
            critic,
            clip_epsilon=ppo["clip_epsilon"],
            entropy_coeff=entropy_coeff,
            critic_coeff=critic_coeff,
            loss_critic_type="l2",
            normalize_advantage=ppo["normalize_advantage"],
        )
        rl_loss.make_value_estimator(
            ValueEstimators.GAE, gamma=gamma, lmbda=ppo["gae_lambda"], **(value_estimator_kwargs or {})
        )
    elif variant.rl:
        rl_loss = A2CLoss(
            actor,
            critic,
            entropy_coeff=entropy_coeff,
            critic_coeff=critic_coeff,
            loss_critic_type="l2",
        )
        rl_loss.make_value_estimator(ValueEstimators.TD1, gamma=gamma, **(value_estimator_kwargs or {}))
    elif entropy_coeff:
        rl_loss = PolicyEntropyLoss(actor, entropy_coeff=entropy_coeff)
    idm_loss = None
    if inverse_model is not None:
        if variant.inverse_model == "dual":
            idm_loss = DualInverseDynamicsLoss(
                inverse_model,
                action_coeff=idm_action_coeff,
                embedding_coeff=idm_embedding_coeff,
                forward_coeff=idm_forward_coeff,
            )
        else:
            idm_loss = InverseDynamicsLoss(inverse_model, action_coeff=idm_action_coeff)
    bc_loss = None
    if variant.bc == "inferred":
        bc_loss = ExpertBCLoss(
            actor,
            inverse_model,
            bc_coeff=bc_coeff,
            labels=bc_labels,
            confidence=bc_confidence,
            entropy_floor=bc_entropy_floor,
            prior_floor=bc_prior_floor,
        )
    elif variant.bc == "true":
        inferred_only = {
            k: v
            for k, v in (
                ("bc_labels", bc_labels != "argmax"),
                ("bc_confidence", bc_confidence > 0),
                ("bc_prior_floor", bc_prior_floor > 0),
            )
            if v
        }
        if inferred_only:
            raise ValueError(
                f"variant {variant.name!r} clones the expert's true actions; {sorted(inferred_only)} "
                "change how inferred labels are read from the inverse model and have no meaning here"
            )
        bc_loss = ExpertBCLoss(actor, None, bc_coeff=bc_coeff, entropy_floor=bc_entropy_floor)
        bc_loss.set_keys(action=expert_action_key)
    return HybridLoss(rl_loss, idm_loss, bc_loss)


def param_groups(loss: HybridLoss) -> list[dict]:
    """Optimiser parameter groups: ``"policy"`` (actor and critic) and
    ``"inverse_model"``, without duplicates."""
    idm = loss.inverse_dynamics_loss
    idm_params = list(idm.parameters()) if idm is not None else []
    idm_ids = {id(p) for p in idm_params}
    policy = [p for p in loss.parameters() if id(p) not in idm_ids]
    groups = [{"params": policy, "name": "policy"}]
    if idm_params:
        groups.append({"params": idm_params, "name": "inverse_model"})
    return groups
