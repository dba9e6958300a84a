"""TorchRL's ``Trainer`` for the hybrid agent: the config schemas every env shares
(:mod:`~torchrl_hybrid.trainers.config`), the run assembly an env family plugs into
(:mod:`~torchrl_hybrid.trainers.run`), the trainer and its optimisation step
(:mod:`~torchrl_hybrid.trainers.trainer`), its hooks and the evaluation."""

from torchrl_hybrid.trainers.evaluation import evaluate_policy, inverse_model_accuracy
from torchrl_hybrid.trainers.hooks import CurriculumHook, DelayedCoefficientHook, ExpertBatchHook, MetricsHook
from torchrl_hybrid.trainers.trainer import ClippedOptimizationStepper, attach_demonstrations, make_trainer

__all__ = [
    "ClippedOptimizationStepper",
    "CurriculumHook",
    "DelayedCoefficientHook",
    "ExpertBatchHook",
    "MetricsHook",
    "attach_demonstrations",
    "evaluate_policy",
    "inverse_model_accuracy",
    "make_trainer",
]
