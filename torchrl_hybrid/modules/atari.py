"""The paper's Atari networks: a shared CNN encoder, linear actor and critic heads."""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable

import torch
from tensordict.nn import InteractionType, TensorDictModule, TensorDictSequential
from tensordict.nn.probabilistic import interaction_type
from torch import nn
from torch.distributions import Categorical
from torchrl.modules import ProbabilisticActor

__all__ = ["AtariEncoder", "AtariCollectionPolicy", "make_atari_actor_critic", "orthogonal_init_"]


class AtariEncoder(nn.Module):
    """conv 32 8x8/4, conv 64 4x4/2, conv 32 3x3/1, fc 512, ReLU after each.

    Note the third convolution has 32 filters (the paper's text), not the usual 64.
    With ``channels_last`` (default) the convolutions run in channels-last memory
    format, which makes their CPU backward pass faster.
    Takes uint8 frame stacks ``[*B, stack, 84, 84]`` (any leading dims) and scales
    them to [0, 1]. ``out_features`` (512) is what the inverse model's ``W_s`` reads.

    Examples:
        >>> AtariEncoder()(torch.zeros(2, 3, 4, 84, 84, dtype=torch.uint8)).shape
        torch.Size([2, 3, 512])
    """

    def __init__(self, stack: int = 4, size: int = 84, out_features: int = 512, channels_last: bool = True):
        super().__init__()
        self.convs = nn.Sequential(
            nn.Conv2d(stack, 32, 8, stride=4),
            nn.ReLU(),
            nn.Conv2d(32, 64, 4, stride=2),
            nn.ReLU(),
            nn.Conv2d(64, 32, 3, stride=1),
            nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            n = self.convs(torch.zeros(1, stack, size, size)).shape[-1]
        self.fc = nn.Sequential(nn.Linear(n, out_features), nn.ReLU())
        self.out_features = out_features
        self.in_shape = (stack, size, size)
        # (weakref to the input frames, key, features, the frames' _version, grad mode)
        self._cache: tuple[weakref.ref, tuple, torch.Tensor, int, bool] | None = None
        self.reuse_features = True
        # oneDNN's convolutions run their CPU backward pass faster on channels-last
        # tensors (benchmarks/atari_profile.py prints both layouts' forward + backward time)
        self.channels_last = channels_last
        if channels_last:
            self.convs.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # missing from torch's stub
        self._compiled: Callable[[torch.Tensor], torch.Tensor] | None = (
            None  # compile_cnn(): the compiled CNN (convs + fc), else the plain modules
        )
        self.compile_mode = "off"

    COMPILE_MODES = ("off", "default", "reduce-overhead", "max-autotune")
    # modes that record a CUDA graph per input shape: batches are padded to a few fixed sizes
    CUDA_GRAPH_MODES = ("reduce-overhead", "max-autotune")

    def compile_cnn(self, mode: str = "default") -> AtariEncoder:
        """Runs the CNN (the convolutions and the 512-unit layer: all of an update's
        FLOPs) through ``torch.compile`` with ``mode`` (``"reduce-overhead"`` adds CUDA
        graphs on a GPU); ``"off"`` goes back to the plain modules. Same weights, same
        parameters (checkpoints and optimisers see no difference); the feature reuse
        around the CNN is unchanged. Measured on a 2-core CPU it is about as fast as the
        plain path (``benchmarks/atari_compile.py``: 1.02x for the learner's forward +
        backward, 1.08x for collection's forward), so the default is off; not measured
        on a GPU yet.

        In the CUDA-graph modes (``reduce-overhead``, ``max-autotune``) every distinct input
        shape records a graph of its own, and the batch sizes vary from update to update
        (episode ends change how many rows feature reuse leaves to the CNN); so the batch
        is padded with zero frames to the next power of two (at least 8) and the padding's
        rows are dropped from the output: at most ``log2`` of the largest batch sizes, each
        in grad and no-grad mode, instead of one graph per batch size. Padded rows cost
        compute (under 2x) and change no other row's features or gradients."""
        if mode not in self.COMPILE_MODES:
            raise ValueError(f"compile={mode!r}: choose one of {self.COMPILE_MODES}")
        # batch sizes vary (collection, learner, the rows feature reuse leaves): torch.compile
        # makes the batch dimension dynamic after its first recompile
        self._compiled = None if mode == "off" else torch.compile(self._cnn, mode=None if mode == "default" else mode)
        self.compile_mode = mode
        return self

    def _cnn(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(self.convs(x))

    def __getstate__(self):  # a compiled function does not pickle (worker collectors copy the policy)
        state = self.__dict__.copy()
        state["_compiled"] = None
        return state

    def __setstate__(self, state):  # a copy (deepcopy, a worker's policy) compiles again, in the same mode
        super().__setstate__(state)
        self.__dict__.setdefault("compile_mode", "off")
        if self.compile_mode != "off":
            self.compile_cnn(self.compile_mode)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        # The CNN dominates the cost of an update, and the losses of one update see the
        # same frames several times; features are reused where that is exact:
        # 1. TorchRL's A2CLoss runs the actor and the critic separately on the same
        #    observation tensor, and the inverse model reads it again: the second and
        #    later calls reuse the first's features (same input storage and version,
        #    same weights; a reshaped view is a hit too). A no-grad call may reuse
        #    grad-mode features, detached; never the other way round.
        # 2. Next observations of a rollout are the following steps' observations: in
        #    grad mode, a call on a tensor shaped like the cached input reuses the
        #    cached features for every row equal to the cached input's next row
        #    (flattening the leading dims; for [envs, time] batches that is every step
        #    but the last one and episode ends), and runs the CNN on the rest only.
        # ``reuse_features = False`` turns both off.
        if not self.reuse_features:
            return self._forward(frames)
        w = self.convs[0].weight
        try:
            key = (frames.data_ptr(), frames.numel(), id(w), w._version)
        except RuntimeError:  # tensors without storage (TorchRL's policy probing): no caching
            return self._forward(frames)
        grad = torch.is_grad_enabled()
        cached = self._cache
        if cached is None:
            out = self._forward(frames)
            if frames.is_contiguous():
                self._cache = (weakref.ref(frames), key, out, frames._version, grad)
            return out
        src = cached[0]()
        # the weak reference keeps the check honest: while the cached input lives, its
        # memory cannot have been reused by another tensor
        valid = src is not None and src._version == cached[3] and frames.is_contiguous()
        if valid and cached[1] == key and (cached[4] == grad or not grad):
            out = cached[2] if cached[4] == grad else cached[2].detach()
            return out.reshape(*frames.shape[:-3], self.out_features)
        if (
            src is not None
            and valid
            and grad
            and cached[4]
            and cached[1][1:] == key[1:]
            and frames.numel() >= 2 * math.prod(self.in_shape)
        ):
            shifted = self._shifted(frames, src, cached[2])
            if shifted is not None:
                return shifted  # not cached: the cache keeps the input the rows were matched against
        out = self._forward(frames)
        # a no-grad call (e.g. the critic on a few next observations before the loss)
        # does not evict features kept for the current update's backward pass
        keep = not grad and valid and cached[4] and cached[1][2:] == key[2:]
        if frames.is_contiguous() and not keep:
            self._cache = (weakref.ref(frames), key, out, frames._version, grad)
        return out

    def remember(self, frames: torch.Tensor, features: torch.Tensor) -> None:
        """Registers ``features`` (``[*frames.shape[:-3], out_features]``, computed by
        this encoder with the current weights and autograd on, e.g. step by step
        during collection) as the output for ``frames``: the next grad-mode call on
        ``frames`` returns them, with their graph, instead of running the CNN again.
        Invalidated as usual when the weights or ``frames`` change."""
        if features.shape != (*frames.shape[:-3], self.out_features):
            raise ValueError(f"features of shape {tuple(features.shape)} do not match frames {tuple(frames.shape)}")
        if not frames.is_contiguous():
            raise ValueError("remember() needs contiguous frames")
        w = self.convs[0].weight
        key = (frames.data_ptr(), frames.numel(), id(w), w._version)
        self._cache = (weakref.ref(frames), key, features, frames._version, features.requires_grad)

    def _shifted(self, frames: torch.Tensor, src: torch.Tensor, src_out: torch.Tensor) -> torch.Tensor | None:
        x = frames.reshape(-1, math.prod(self.in_shape))
        y = src.reshape(x.shape)
        if x.dtype == torch.uint8 and x.shape[1] % 8 == 0:  # compare 8 bytes at a time
            x, y = x.view(torch.int64), y.view(torch.int64)
        same = (x[:-1] == y[1:]).all(-1)  # row i of frames == row i + 1 of src
        n, dev = x.shape[0], frames.device
        need = torch.ones(n, dtype=torch.bool, device=dev)
        need[:-1] = ~same
        # one device-to-host sync: the rows the CNN must run on (their count sizes the batch)
        fresh_rows = need.nonzero().squeeze(-1)
        if fresh_rows.numel() == n:  # nothing to reuse
            return None
        fresh = self._forward(frames.reshape(n, *self.in_shape)[fresh_rows])
        # row i takes row i + 1 of the cached features where it matched, else its fresh row
        index = torch.arange(1, n + 1, device=dev)
        index[fresh_rows] = torch.arange(n, n + fresh_rows.numel(), device=dev)
        feats = torch.cat([src_out.reshape(n, self.out_features), fresh])[index]
        return feats.reshape(*frames.shape[:-3], self.out_features)

    def _forward(self, frames: torch.Tensor) -> torch.Tensor:
        lead = frames.shape[:-3]
        if tuple(frames.shape[-3:]) != self.in_shape:
            raise ValueError(f"expected frame stacks of shape {self.in_shape}, got {tuple(frames.shape[-3:])}")
        x = frames.reshape(-1, *self.in_shape).float().div_(255.0)
        if self.channels_last:
            try:
                x = x.contiguous(memory_format=torch.channels_last)
            except RuntimeError:  # inside torch.vmap (TorchRL's value estimators): keep the layout
                pass
        if self._compiled is None:
            return self._cnn(x).reshape(*lead, self.out_features)
        n = x.shape[0]
        if self.compile_mode in self.CUDA_GRAPH_MODES and n != padded_batch_size(n):
            fmt = (
                torch.channels_last
                if self.channels_last and x.dim() == 4 and x.is_contiguous(memory_format=torch.channels_last)
                else torch.contiguous_format
            )
            padded = x.new_zeros((padded_batch_size(n), *x.shape[1:])).contiguous(memory_format=fmt)
            padded[:n] = x
            return self._compiled(padded)[:n].reshape(*lead, self.out_features)
        return self._compiled(x).reshape(*lead, self.out_features)


def padded_batch_size(n: int) -> int:
    """The batch size a CUDA-graph compiled CNN runs ``n`` rows at: the next power of two,
    at least 8."""
    return max(8, 1 << (max(n, 1) - 1).bit_length())


def orthogonal_init_(module: nn.Module, gain: float) -> nn.Module:
    """Orthogonal weights with ``gain`` and zero biases, for every conv/linear layer
    (the A2C initialisation of the authors' base code and of Stable-Baselines3)."""
    for m in module.modules():
        if isinstance(m, (nn.Conv2d, nn.Linear)):
            w = torch.empty(m.weight.shape)  # contiguous: orthogonal_ views it as a matrix
            nn.init.orthogonal_(w, gain)
            with torch.no_grad():
                m.weight.copy_(w)  # keeps the weight's memory format (channels-last convs)
            if m.bias is not None:
                nn.init.zeros_(m.bias)
    return module


class AtariCollectionPolicy(nn.Module):
    """Actor and critic heads on one encoder pass, for collection: returns
    ``(action, action_log_prob, state_value)``.

    Equivalent to running the :class:`~torchrl.modules.ProbabilisticActor` and the
    value head built by :func:`make_atari_actor_critic`, in one module call: the
    collector calls the policy once per env step on a small batch, where the
    tensordict plumbing of the composed modules costs more than the CNN. Samples
    under ``ExplorationType.RANDOM`` (what TorchRL collectors set), takes the most
    likely action otherwise (the :class:`ProbabilisticActor` default).
    """

    def __init__(self, encoder: nn.Module, policy_head: nn.Linear, value_head: nn.Linear):
        super().__init__()
        self.encoder, self.policy_head, self.value_head = encoder, policy_head, value_head

    def forward(self, observation: torch.Tensor):
        return self.heads(self.encoder(observation))

    def heads(self, feats: torch.Tensor):
        """``(action, action_log_prob, state_value)`` from encoder features."""
        logits = self.policy_head(feats)
        log_p = logits.log_softmax(-1)
        if interaction_type() == InteractionType.RANDOM:
            flat = log_p.reshape(-1, log_p.shape[-1]).exp()
            action = torch.multinomial(flat, 1).reshape(log_p.shape[:-1])
        else:
            action = log_p.argmax(-1)
        return action, log_p.gather(-1, action.unsqueeze(-1)).squeeze(-1), self.value_head(feats)


def make_atari_actor_critic(n_actions: int, encoder: AtariEncoder | None = None, init: str = "orthogonal"):
    """Actor and critic sharing one :class:`AtariEncoder`, and the collection policy.

    Returns ``(actor, critic, encoder, collection_policy)``: the collection policy
    (an :class:`AtariCollectionPolicy` in a ``TensorDictModule``) samples the action
    and also writes the critic's ``state_value`` from the same features, so that the
    value estimator need not run the CNN again on the batch (see
    :class:`~torchrl_hybrid.trainers.hooks.NextStateValueHook`). The encoder is
    returned so that the inverse model can share it, as in the paper.
    """
    if init not in ("orthogonal", "default"):
        raise ValueError(f"init must be 'orthogonal' or 'default', got {init!r}")
    new_encoder = encoder is None
    encoder = encoder if encoder is not None else AtariEncoder()
    policy_linear, value_linear = nn.Linear(encoder.out_features, n_actions), nn.Linear(encoder.out_features, 1)
    if init == "orthogonal":
        # gains as in the authors' A2C base code: sqrt(2) for ReLU layers, 0.01 for the
        # policy head (near-uniform initial policy), 1 for the value head
        if new_encoder:
            orthogonal_init_(encoder, math.sqrt(2))
        orthogonal_init_(policy_linear, 0.01)
        orthogonal_init_(value_linear, 1.0)
    features = TensorDictModule(encoder, in_keys=["observation"], out_keys=["features"])
    policy_head = TensorDictModule(policy_linear, in_keys=["features"], out_keys=["logits"])
    value_head = TensorDictModule(value_linear, in_keys=["features"], out_keys=["state_value"])
    actor = ProbabilisticActor(
        TensorDictSequential(features, policy_head),
        in_keys=["logits"],
        out_keys=["action"],
        distribution_class=Categorical,
        return_log_prob=True,
    )
    critic = TensorDictSequential(features, value_head, selected_out_keys=["state_value"])
    collection_policy = TensorDictModule(
        AtariCollectionPolicy(encoder, policy_linear, value_linear),
        in_keys=["observation"],
        out_keys=["action", "action_log_prob", "state_value"],
    )
    return actor, critic, encoder, collection_policy
