"""Atari through ale-py's threaded vector env, as a TorchRL ``EnvBase``.

``ale_py.vector_env.AtariVectorEnv`` does the standard preprocessing in C++
(frame-skip 4 with max-pooling of the last two frames, 84x84 greyscale, 4
stacked frames, up to 30 no-op starts) for a whole batch of games on worker
threads. TorchRL's ``GymWrapper`` refuses its default autoreset mode, so this
wrapper drives it in ``SameStep`` mode and restores TorchRL's semantics:
``("next", "observation")`` of a final step is the true last frame stack (from
``info["final_obs"]``), and the next root observation is the new episode's
first one. Lives are exposed under ``"lives"`` so that demonstrations can be cut
at the first life lost.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

__all__ = ["ATARI_GAMES", "AtariEnv", "action_classes", "action_names", "rom_path"]

#: the paper's eight games
ATARI_GAMES = ("Alien", "BeamRider", "Breakout", "MsPacman", "Pong", "Qbert", "Seaquest", "SpaceInvaders")


def _rom_name(game: str) -> str:
    # "MsPacman" -> "ms_pacman", "SpaceInvaders" -> "space_invaders", "pong" -> "pong"
    out = []
    for i, ch in enumerate(game):
        if ch.isupper() and i and not game[i - 1].isupper():
            out.append("_")
        out.append(ch.lower())
    return "".join(out)


def action_names(game: str) -> list[str]:
    """The names of ``game``'s actions in the order :class:`AtariEnv` numbers them (ALE's
    minimal action set), e.g. ``["NOOP", "FIRE", "RIGHT", "LEFT"]`` for Breakout."""
    try:
        from ale_py import ALEInterface, LoggerMode, roms
    except ImportError as err:  # pragma: no cover - ale-py is the atari extra
        raise ImportError("Atari needs ale-py: pip install 'torchrl-hybrid[atari]'") from err
    known = roms.get_all_rom_ids()
    if _rom_name(game) not in known:
        names = ", ".join(sorted("".join(w.capitalize() for w in r.split("_")) for r in known))
        raise ValueError(f"unknown Atari game {game!r}; ale-py has: {names}")
    ALEInterface.setLoggerMode(LoggerMode.Error)  # no ROM banner on stderr (a process-wide ALE setting)
    ale = ALEInterface()
    rom = roms.get_rom_path(_rom_name(game))
    if rom is None:
        raise ValueError(f"ale-py lists {game!r} but ships no ROM file for it; reinstall ale-py")
    ale.loadROM(rom)
    return [a.name for a in ale.getMinimalActionSet()]


class AtariEnv(EnvBase):
    """A batch of ``num_envs`` Atari games with standard preprocessing.

    Args:
        game: an ALE game, e.g. ``"Pong"`` or ``"MsPacman"``.
        num_envs: parallel games (the paper: 16).

    Keyword Args:
        seed: seed of the first reset.
        num_threads: ALE worker threads (0 = one per env, capped by ale-py).
        noop_max: up to this many no-ops at each episode start (standard: 30).
        frameskip: frames per step (standard: 4).
        stack: frames stacked per observation (standard: 4).
        size: side of the square greyscale frames (standard: 84).
        reward_clipping: ``reward`` is the sign of the game reward (for training);
            the raw reward is always in ``"score"``.
        max_episode_frames: truncate episodes after this many frames (standard: 108,000).
        repeat_action_probability: sticky actions (0 = off, the paper's setting).

    Examples:
        >>> env = AtariEnv("Pong", num_envs=2)
        >>> env.rollout(3)["observation"].shape
        torch.Size([2, 3, 4, 84, 84])
    """

    batch_locked = True

    def __init__(
        self,
        game: str,
        num_envs: int = 16,
        *,
        seed: int = 0,
        num_threads: int = 0,
        noop_max: int = 30,
        frameskip: int = 4,
        stack: int = 4,
        size: int = 84,
        reward_clipping: bool = True,
        max_episode_frames: int = 108_000,
        repeat_action_probability: float = 0.0,
    ):
        try:
            import ale_py
            from ale_py.vector_env import AtariVectorEnv
        except ImportError as err:  # pragma: no cover - depends on the install
            raise ImportError("Atari needs ale-py: pip install 'torchrl-hybrid[atari]'") from err
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        super().__init__(batch_size=(num_envs,), device="cpu")
        self.game = game
        self.preprocessing = {
            "noop_max": noop_max,
            "frameskip": frameskip,
            "stack": stack,
            "size": size,
            "grayscale": True,
            "maxpool": True,
            "reward_clipping": reward_clipping,
            "max_episode_frames": max_episode_frames,
            "repeat_action_probability": repeat_action_probability,
        }
        import ale_py.roms

        known = ale_py.roms.get_all_rom_ids()
        if _rom_name(game) not in known:
            names = ", ".join(sorted("".join(w.capitalize() for w in r.split("_")) for r in known))
            raise ValueError(f"unknown Atari game {game!r}; ale-py {ale_py.__version__} has: {names}")
        try:
            self._env = AtariVectorEnv(
                _rom_name(game),
                num_envs,
                num_threads=num_threads,
                autoreset_mode="SameStep",
                noop_max=noop_max,
                frameskip=frameskip,
                stack_num=stack,
                img_height=size,
                img_width=size,
                grayscale=True,
                maxpool=True,
                reward_clipping=False,
                episodic_life=False,
                max_num_frames_per_episode=max_episode_frames,
                repeat_action_probability=repeat_action_probability,
            )
        except Exception as err:
            raise ValueError(f"ale-py cannot load the game {game!r}: {err}") from err
        self.reward_clipping = reward_clipping
        self._seed = seed
        self._started = False
        self._pending: torch.Tensor | None = None  # reset observations of envs that just finished
        self._pending_mask: torch.Tensor | None = None
        self._lives = torch.zeros(num_envs, 1, dtype=torch.int64)  # set by every reset and step
        self._obs = torch.zeros(num_envs, stack, size, size, dtype=torch.uint8)
        n = num_envs
        obs_shape = (n, stack, size, size)
        self.n_actions = int(self._env.single_action_space.n)  # type: ignore[attr-defined]  # Discrete
        self.observation_spec = Composite(
            observation=Bounded(0, 255, shape=obs_shape, dtype=torch.uint8),
            lives=Unbounded(shape=(n, 1), dtype=torch.int64),
            shape=(n,),
        )
        self.action_spec = Categorical(self.n_actions, shape=(n,), dtype=torch.int64)
        self.reward_spec = Composite(
            reward=Unbounded(shape=(n, 1), dtype=torch.float32),
            score=Unbounded(shape=(n, 1), dtype=torch.float32),
            shape=(n,),
        )
        self.done_spec = Composite(
            done=Categorical(2, shape=(n, 1), dtype=torch.bool),
            terminated=Categorical(2, shape=(n, 1), dtype=torch.bool),
            truncated=Categorical(2, shape=(n, 1), dtype=torch.bool),
            shape=(n,),
        )

    def _done_td(self, n):
        z = torch.zeros(n, 1, dtype=torch.bool)
        return {"done": z, "terminated": z.clone(), "truncated": z.clone()}

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        n = self.batch_size[0]
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if not self._started or mask is None or mask.all() and self._pending is None:
            obs, info = self._env.reset(seed=self._seed)
            self._started, self._pending = True, None
            self._obs = torch.from_numpy(np.ascontiguousarray(obs))
            self._lives = torch.as_tensor(info["lives"], dtype=torch.int64).view(n, 1)
        else:
            # the vector env already started new episodes for the envs that ended
            mask = mask.reshape(n)
            if self._pending is None or self._pending_mask is None or (mask & ~self._pending_mask).any():
                raise RuntimeError(
                    "AtariEnv can only reset envs whose episode just ended (ale-py resets them itself); "
                    "reset the whole batch instead"
                )
            self._obs = torch.where(mask.view(n, 1, 1, 1), self._pending, self._obs)
            self._pending = None
        return TensorDict({"observation": self._obs.clone(), "lives": self._lives.clone(), **self._done_td(n)}, [n])

    def check_policy(self, policy: torch.nn.Module) -> None:
        """Refuses a policy whose last linear layer (its action head) does not have
        this game's number of actions, e.g. a checkpoint trained on another game;
        closes the env first."""
        heads = [m for m in policy.modules() if isinstance(m, torch.nn.Linear)]
        n = heads[-1].out_features if heads else None
        if n is not None and n != self.n_actions:
            self.close()
            raise ValueError(
                f"the policy has {n} actions but {self.game} has {self.n_actions}: "
                "is the checkpoint made for another game?"
            )

    def send(self, action) -> None:
        """Starts a step of every game with ``action`` (``[num_envs]`` ints) and returns
        at once: ale-py steps the games on its worker threads until :meth:`recv`.
        Actions outside ``[0, n_actions)`` are refused (ale-py would hang on them)."""
        n = self.batch_size[0]
        a = action.reshape(n).numpy() if isinstance(action, torch.Tensor) else np.asarray(action).reshape(n)
        if a.dtype not in (np.int64, np.int32):
            raise TypeError(f"{self.game}: actions must be integers, got dtype {a.dtype}")
        lo, hi = int(a.min()), int(a.max())
        if lo < 0 or hi >= self.n_actions:
            raise ValueError(
                f"{self.game} has {self.n_actions} actions (0..{self.n_actions - 1}), got action {hi if hi >= self.n_actions else lo}; "
                "is the policy (or checkpoint) made for another game?"
            )
        self._env.send(a)

    def recv(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
        """Waits for the step started by :meth:`send`. Returns numpy arrays
        ``(obs, score, terminated, truncated, final_obs, lives)``: ``obs`` is the
        new episode's first frame stack where an episode ended, ``final_obs`` (or
        ``None`` when no episode ended) the old episode's last one for every env,
        ``score`` the raw game reward."""
        obs, reward, term, trunc, info = self._env.recv()
        trunc = trunc & ~term
        final = info["final_obs"] if (term | trunc).any() else None
        return obs, reward, term, trunc, final, info["lives"]

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        n = self.batch_size[0]
        self.send(tensordict.get("action"))
        obs, reward, term, trunc, final, lives = self.recv()
        obs_t = torch.from_numpy(np.ascontiguousarray(obs))
        term_t = torch.as_tensor(term, dtype=torch.bool)
        trunc_t = torch.as_tensor(trunc, dtype=torch.bool)
        done = term_t | trunc_t
        next_obs = obs_t
        if final is not None:
            final_t = torch.from_numpy(np.ascontiguousarray(final))
            next_obs = torch.where(done.view(n, 1, 1, 1), final_t, obs_t)
            self._pending, self._pending_mask = obs_t, done
        self._obs = next_obs
        self._lives = torch.as_tensor(lives, dtype=torch.int64).view(n, 1)
        score = torch.as_tensor(reward, dtype=torch.float32).view(n, 1)
        return TensorDict(
            {
                "observation": next_obs,
                "lives": self._lives.clone(),
                "reward": score.sign() if self.reward_clipping else score,
                "score": score,
                "done": done.view(n, 1),
                "terminated": term_t.view(n, 1),
                "truncated": trunc_t.view(n, 1),
            },
            [n],
        )

    def reset_all(self, seed: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Starts every game anew (seeded with ``seed``, else the env's seed) and
        returns numpy ``(obs, lives)``; for collectors that drive :meth:`send` /
        :meth:`recv` themselves."""
        obs, info = self._env.reset(seed=self._seed if seed is None else int(seed))
        self._started, self._pending = True, None
        return obs, info["lives"]

    def _set_seed(self, seed: int | None) -> None:
        self._seed = 0 if seed is None else int(seed)
        self._started = False

    def close(self, **kwargs):
        if getattr(self, "_env", None) is not None:
            self._env.close()
            self._env = None
        super().close(**kwargs)


def rom_path(game: str) -> Path:
    """ale-py's ROM of ``game`` (BeamRider -> beam_rider); ``ValueError`` if it has none."""
    from ale_py import roms

    rom = roms.get_rom_path(_rom_name(game))
    if rom is None:
        raise ValueError(f"no ROM for {game!r} in ale-py")
    return rom


def action_classes(game: str, states: int, seed: int = 0, frameskip: int = 4) -> dict:
    """Which of ``game``'s actions (s, s') can tell apart at all: an upper bound on what any
    inverse model can label. Plays ``states`` steps of uniformly random actions (frame skip
    ``frameskip``, no sticky actions, as the training env); at each, saves the emulator state,
    plays every action once from it and compares the next screens (grayscale, full
    resolution, the max of the last two frames as the preprocessing takes). Returns the share
    of states where no action changes the next screen (``no_action_visible``), where all do
    (``all_distinct``), the mean number of classes of equal next screens, and their histogram.
    ``benchmarks/atari_action_effect.py`` runs it over games from the command line."""
    import numpy as np
    from ale_py import ALEInterface, LoggerMode

    rom = rom_path(game)
    ALEInterface.setLoggerMode(LoggerMode.Error)
    ale = ALEInterface()
    ale.setInt("random_seed", seed)
    ale.setFloat("repeat_action_probability", 0.0)
    ale.loadROM(rom)
    actions = list(ale.getMinimalActionSet())
    rng = np.random.default_rng(seed)

    def step(a) -> np.ndarray:
        frames = []
        for i in range(frameskip):
            ale.act(a)
            if i >= frameskip - 2:
                frames.append(ale.getScreenGrayscale())
        return np.maximum(*frames) if len(frames) == 2 else frames[-1]

    counts = []
    for _ in range(states):
        if ale.game_over():
            ale.reset_game()
        saved = ale.cloneState()
        screens = []
        for a in actions:
            ale.restoreState(saved)
            screens.append(step(a).tobytes())
        counts.append(len(set(screens)))
        ale.restoreState(saved)
        step(actions[int(rng.integers(len(actions)))])
    c = np.array(counts)
    n = len(actions)
    return {
        "game": game,
        "actions": n,
        "states": states,
        "no_action_visible": float((c == 1).mean()),
        "all_distinct": float((c == n).mean()),
        "mean_classes": float(c.mean()),
        "classes_histogram": {int(k): int((c == k).sum()) for k in range(1, n + 1)},
    }
