"""Trainer hooks and assembly of the hybrid agent on TorchRL's ``Trainer``."""

from torchrl_hybrid.trainers.evaluation import evaluate_policy, inverse_model_accuracy
from torchrl_hybrid.trainers.hooks import CurriculumHook, DelayedCoefficientHook, ExpertBatchHook, MetricsHook
from torchrl_hybrid.trainers.hybrid import VARIANTS, Variant, get_variant, make_hybrid_loss, make_trainer, param_groups

__all__ = [
    "VARIANTS",
    "CurriculumHook",
    "DelayedCoefficientHook",
    "ExpertBatchHook",
    "MetricsHook",
    "Variant",
    "evaluate_policy",
    "get_variant",
    "inverse_model_accuracy",
    "make_hybrid_loss",
    "make_trainer",
    "param_groups",
]
