"""Test helpers that ship with the library (like ``torch.testing``)."""

from torchrl_hybrid.testing.device_rules import DeviceRuleBreach, DeviceRuleCheck, StandInTensor, register_stand_in

__all__ = ["DeviceRuleCheck", "DeviceRuleBreach", "StandInTensor", "register_stand_in"]
