"""Env families: what an env brings to the one run assembly (:mod:`torchrl_hybrid.trainers.run`).

- :mod:`~torchrl_hybrid.families.gym`: every gymnasium env with discrete actions (Taxi and the other
  toy-text envs, CartPole, Acrobot, MountainCar, LunarLander, your own): ``GymConfig``, ``GymFamily``,
  ``train_gym``. Taxi is its preset ``recipes/config/taxi.yaml``.
- :mod:`~torchrl_hybrid.families.gym_batched`: the gym family's fast path for tabular envs
  (``engine=batched``): many seeds in one batched process, for the paper's Taxi sweeps.
- :mod:`~torchrl_hybrid.families.atari`: ale-py's games, the paper's CNN: ``AtariConfig``,
  ``AtariFamily``, ``train_atari``.

The modules are imported on use (``from torchrl_hybrid.families.gym import train_gym``): each pulls
in its own env stack.
"""
