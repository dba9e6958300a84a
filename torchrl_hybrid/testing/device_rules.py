"""CUDA's device rules, checked on a machine without a GPU.

:class:`DeviceRuleCheck` is a context manager under which ``device="cuda"`` resolves to a
stand-in device. Tensors "on" it are :class:`StandInTensor` objects: they report
``device.type == "standin"``, hold their data in a CPU tensor, and every op on them runs on
the CPU (through the subclass's ``__torch_dispatch__``, or the stand-in backend's kernels for
factories such as ``torch.empty(..., device=...)``), after CUDA's rules are applied and each
breach is recorded with the source line that caused it:

- an op that mixes stand-in tensors with CPU tensors of ``ndim > 0`` (CUDA raises
  "Expected all tensors to be on the same device"; 0-dim CPU tensors are allowed, as on
  CUDA);
- a CPU tensor indexed with a stand-in index (CUDA raises);
- a CPU ``torch.Generator`` handed to an op that runs on the device (CUDA raises);
- ``.numpy()`` of a stand-in tensor (CUDA raises: it needs ``.cpu()`` first).

It also counts device-to-host syncs (``.item()``, ``bool()``, ``float()``, ``.tolist()``,
``.cpu()``, ``nonzero``, boolean-mask indexing, ...) per source line, so that a test can
bound the syncs per update.

The stand-in device is ``standin:0``, PyTorch's PrivateUse1 backend registered from Python
(once per process): a CPU-only PyTorch cannot create tensors that report ``cuda`` (its
lazy CUDA init and autograd's device guards need a CUDA build), and ``meta`` tensors are
taken by TorchRL for uninitialised weights.

Examples:
    >>> with DeviceRuleCheck() as check:
    ...     dev = check.device
    ...     x = torch.ones(3, device=dev)
    ...     _ = x + torch.ones(3)          # a CPU tensor of ndim 1 meets a device tensor
    ...     _ = x + torch.tensor(2.0)      # a 0-dim CPU tensor: allowed, as on CUDA
    >>> [b.rule for b in check.breaches]
    ['mixed devices']
"""

from __future__ import annotations

import collections
import contextlib
import functools
import os
import sys
import sysconfig
import traceback
from dataclasses import dataclass
from typing import Any

import torch
from torch.utils._pytree import tree_flatten, tree_map

__all__ = ["DeviceRuleCheck", "DeviceRuleBreach", "StandInTensor", "STAND_IN_NAME", "register_stand_in"]

STAND_IN_NAME = "standin"
aten = torch.ops.aten


def register_stand_in() -> torch.device:
    """Registers the stand-in as PyTorch's PrivateUse1 backend, implemented in Python
    (once per process): it gets a device guard, so autograd and the optimisers treat it
    as an accelerator. Returns the device, ``standin:0``.

    Call it before the process's first backward pass (a test suite's ``conftest.py``):
    autograd sizes its per-device queues once, at the first backward, from the devices
    registered then. A :class:`DeviceRuleCheck` registers it too, and says so when it is
    too late. From then on ``torch.accelerator.is_available()`` is true in the process;
    ``torch.cuda`` is untouched."""
    from torch.utils.backend_registration import _setup_privateuseone_for_python_backend

    global _DEVICE
    if _DEVICE is not None:
        return _DEVICE
    name = torch._C._get_privateuse1_backend_name()
    if name != "privateuseone":
        raise RuntimeError(
            f"DeviceRuleCheck needs PyTorch's PrivateUse1 backend, but this process has already "
            f"given it to {name!r}; run the check in a process without that backend"
        )
    _setup_privateuseone_for_python_backend(STAND_IN_NAME, backend_module=_StandInModule())
    # Ops reach the backend itself, not StandInTensor.__torch_dispatch__, when no argument is a
    # stand-in tensor (factories: torch.empty(..., device="standin")) or when C++ code has
    # switched Python dispatch off (torch.tensor(x, device=...) copies into a fresh tensor).
    # They go to the active check: registered op by op (a boxed Python fallback alone fails
    # PyTorch's internal assert for some of them), with a fallback for the rest.
    global _LIBRARIES
    aten_lib, any_lib = torch.library.Library("aten", "IMPL"), torch.library.Library("_", "IMPL")
    for name in _BACKEND_OPS:
        op = getattr(aten, name.split(".")[0])
        overload = getattr(op, name.split(".")[1] if "." in name else "default")
        aten_lib.impl(name, functools.partial(_backend_kernel, overload), "PrivateUse1")
    any_lib.fallback(_backend_fallback, "PrivateUse1")
    _LIBRARIES = (aten_lib, any_lib)
    _DEVICE = torch.device(STAND_IN_NAME, 0)
    return _DEVICE


def _check_autograd_sees_the_device() -> None:
    w = StandInTensor(torch.ones(2), requires_grad=True)
    check = DeviceRuleCheck.current()
    try:
        (w * 2.0).sum().backward()
    except RuntimeError as err:
        if "device_ready_queues_" not in str(err):
            raise
        raise RuntimeError(
            "DeviceRuleCheck: this process ran a backward pass before the stand-in device was "
            "registered, so autograd has no queue for it; call "
            "torchrl_hybrid.testing.register_stand_in() first (e.g. in conftest.py)"
        ) from None
    finally:
        if check is not None:
            check.syncs.clear()


_LIBRARIES = ()
_BACKEND_OPS = (
    "empty.memory_format",
    "empty_strided",
    "copy_",
    "_copy_from",
    "_copy_from_and_resize",
    "_to_copy",
    "set_.source_Storage_storage_offset",
    "resize_",
    "_local_scalar_dense",
    "view",
    "as_strided",
)


def _backend_kernel(op, *args, **kwargs):
    return _backend_fallback(op, *args, **kwargs)


def _backend_fallback(op, *args, **kwargs):
    check = DeviceRuleCheck.current()
    if check is None:
        raise RuntimeError(f"{op}: the {STAND_IN_NAME!r} device exists only inside a DeviceRuleCheck")
    return check._dispatch(op, args, kwargs)


class _StandInModule:
    """``torch.standin``: what TorchRL and tensordict ask of a device module. The stand-in's
    random numbers come from the CPU generator its ops run on."""

    def is_initialized(self) -> bool:
        return True

    def is_available(self) -> bool:
        return True

    def current_device(self) -> int:
        return 0

    def device_count(self) -> int:
        return 1

    def _is_in_bad_fork(self) -> bool:
        return False

    def synchronize(self, device=None) -> None:
        # tensordict calls it after .to(<a device that is not "cuda">), which a CUDA run does
        # not; syncs are counted from the ops that read device data on the host instead
        return None

    def manual_seed(self, seed: int) -> None:
        pass

    def manual_seed_all(self, seed: int) -> None:
        pass


_DEVICE: torch.device | None = None  # torch.device("standin", 0), once registered

# ops whose result size or value the host must read from the device: a sync on CUDA
_SYNC_OPS = {
    aten._local_scalar_dense.default,  # .item(), bool(), float(), int()
    aten.nonzero.default,
    aten.nonzero_static.default,
    aten.masked_select.default,
    aten.equal.default,
    aten.is_nonzero.default,
    aten._unique2.default,
    aten.unique_consecutive.default,
    aten.unique_dim.default,
    aten.repeat_interleave.Tensor,
}
_FACTORY_KWARGS = ("device",)


@dataclass
class DeviceRuleBreach:
    """One op that CUDA would refuse: the rule, what was seen, and where (``file:line``)."""

    rule: str
    op: str
    detail: str
    where: str

    def __str__(self) -> str:
        return f"{self.where}: {self.rule} in {self.op}: {self.detail}"


class StandInTensor(torch.Tensor):
    """A tensor that reports the stand-in device (``standin:0``) and keeps its data in a CPU tensor
    (``.elem``). Made by the ops of a :class:`DeviceRuleCheck`, never by hand."""

    elem: torch.Tensor

    @staticmethod
    def __new__(cls, elem: torch.Tensor, requires_grad: bool | None = None):
        if isinstance(elem, StandInTensor):
            raise TypeError("StandInTensor wraps a CPU tensor, not another StandInTensor")
        r = torch.Tensor._make_wrapper_subclass(
            cls,
            elem.size(),
            strides=elem.stride(),
            storage_offset=elem.storage_offset(),
            dtype=elem.dtype,
            layout=elem.layout,
            device=_DEVICE,
            requires_grad=elem.requires_grad if requires_grad is None else requires_grad,
            # sizes and strides are read from the CPU data on every query: an out= op
            # (torch.arange(..., device=) fills an empty tensor) resizes the data, not the wrapper
            dispatch_sizes_strides_policy="sizes",
        )
        r.elem = elem
        return r

    def __repr__(self, *, tensor_contents=None):
        return f"StandInTensor({self.elem!r})"

    @classmethod
    def __torch_function__(cls, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        name = getattr(func, "__name__", "")
        if name == "data_ptr":
            return args[0].elem.data_ptr()
        if name in ("numpy", "tolist", "__array__"):
            check = DeviceRuleCheck.current()
            if name == "numpy" or name == "__array__":
                if check is not None:
                    check._breach("numpy() of a device tensor", f"Tensor.{name}", "CUDA needs .cpu() first")
            elif check is not None:
                check._sync(f"Tensor.{name}")
            return getattr(args[0].elem, name)(*args[1:], **kwargs)
        with torch._C.DisableTorchFunctionSubclass():
            return func(*args, **kwargs)

    @classmethod
    def __torch_dispatch__(cls, func, types, args=(), kwargs=None):
        meta = _METADATA_OPS.get(func)
        if meta is not None:
            return meta(args[0].elem, *args[1:])
        check = DeviceRuleCheck.current()
        if check is None:  # outside any check (e.g. another thread): plain CPU semantics
            return DeviceRuleCheck._run(func, args, kwargs or {}, None)
        return check._dispatch(func, args, kwargs or {})

    def __reduce_ex__(self, proto):
        return _rebuild_stand_in, (self.elem,)


_METADATA_OPS = {
    aten.sym_size.default: lambda t: t.size(),
    aten.sym_stride.default: lambda t: t.stride(),
    aten.sym_numel.default: lambda t: t.numel(),
    aten.sym_storage_offset.default: lambda t: t.storage_offset(),
    aten.dim.default: lambda t: t.dim(),
    aten.is_contiguous.default: lambda t: t.is_contiguous(),
    aten.is_contiguous.memory_format: lambda t, fmt: t.is_contiguous(memory_format=fmt),
    aten.is_strides_like_format.default: lambda t, fmt: t.is_contiguous(memory_format=fmt),
    aten.is_non_overlapping_and_dense.default: lambda t: (
        torch._C._is_non_overlapping_and_dense(t)
        if hasattr(torch._C, "_is_non_overlapping_and_dense")
        else t.is_contiguous()
    ),
}


def _rebuild_stand_in(elem: torch.Tensor) -> torch.Tensor:
    """Unpickles a stand-in tensor: a stand-in again while a check is active, else its CPU
    data (as ``torch.load(map_location="cpu")`` gives a CUDA tensor's)."""
    return StandInTensor(elem) if DeviceRuleCheck.current() is not None else elem


def _is_stand_in_device(d) -> bool:
    if isinstance(d, str):
        return d.split(":")[0] == STAND_IN_NAME
    return isinstance(d, torch.device) and d.type == STAND_IN_NAME


class DeviceRuleCheck:
    """Context manager: ``device="cuda"`` becomes a stand-in device whose ops run on the
    CPU under CUDA's device rules. Breaches are recorded in :attr:`breaches`; syncs are
    counted per source line in :attr:`syncs`.

    Args:
        raise_on_breach: raise :class:`RuntimeError` at the first breach instead of
            recording it (useful to get a full traceback).
    """

    _active: list[DeviceRuleCheck] = []
    _autograd_checked = False

    def __init__(self, raise_on_breach: bool = False):
        self.raise_on_breach = raise_on_breach
        self.breaches: list[DeviceRuleBreach] = []
        self.syncs: collections.Counter[str] = collections.Counter()
        self.device = register_stand_in()  # what resolve_device("cuda") gives inside the check
        self._stack = contextlib.ExitStack()

    # -- entering and leaving --------------------------------------------------------
    @classmethod
    def current(cls) -> DeviceRuleCheck | None:
        return cls._active[-1] if cls._active else None

    def __enter__(self) -> DeviceRuleCheck:
        from torchrl_hybrid.utils import device as device_mod

        register_stand_in()

        DeviceRuleCheck._active.append(self)
        if not DeviceRuleCheck._autograd_checked:
            _check_autograd_sees_the_device()
            DeviceRuleCheck._autograd_checked = True
        self._stack.enter_context(_patched(device_mod, "_STAND_IN", self.device))
        torch.serialization.add_safe_globals([_rebuild_stand_in, StandInTensor])
        # nn.Module.to() keeps each parameter's identity on CUDA (it assigns .data); a subclass
        # cannot take .data from a plain tensor, so the objects are swapped in place instead,
        # which also keeps identity (TorchRL's losses hold their parameters in TensorDicts)
        self._stack.enter_context(_swap_on_conversion())
        for patch in _third_party_patches():
            self._stack.enter_context(patch)
        return self

    def __exit__(self, *exc) -> None:
        try:
            self._stack.close()
        finally:
            DeviceRuleCheck._active.remove(self)

    # -- reports ---------------------------------------------------------------------
    def total_syncs(self) -> int:
        return sum(self.syncs.values())

    def report(self) -> str:
        lines = [f"{len(self.breaches)} breach(es) of CUDA's device rules"]
        seen = collections.Counter(str(b) for b in self.breaches)
        lines += [f"  {n}x {b}" for b, n in seen.items()]
        lines.append(f"{self.total_syncs()} device-to-host sync(s):")
        lines += [f"  {n:6d}  {w}" for w, n in self.syncs.most_common()]
        return "\n".join(lines)

    # -- the rules ---------------------------------------------------------------------
    def _where(self) -> str:
        """The innermost frame of the caller's own code (outside installed packages, the
        standard library and this file): the line that issued the op, followed by the
        innermost library frame when the op was issued inside a library
        (``torchrl_hybrid/trainers/run.py:513 via torchrl/collectors/_single.py:2140``)."""
        here = os.path.abspath(__file__)
        frame = sys._getframe(1)
        library = None
        while frame is not None:
            f = os.path.abspath(frame.f_code.co_filename)
            if f != here and not f.startswith("<"):
                if not f.startswith(_LIBRARY_ROOTS):
                    own = f"{_short(f)}:{frame.f_lineno}"
                    return own if library is None else f"{own} via {library}"
                if library is None and not _is_plumbing(f):
                    library = f"{_short(f)}:{frame.f_lineno}"
            frame = frame.f_back
        return library or "?"

    def _breach(self, rule: str, op: str, detail: str) -> None:
        b = DeviceRuleBreach(rule, op, detail, self._where())
        if self.raise_on_breach:
            raise RuntimeError(f"device rule breached: {b}\n{''.join(traceback.format_stack()[-12:])}")
        self.breaches.append(b)

    def _sync(self, op: str) -> None:
        self.syncs[f"{self._where()} ({op})"] += 1

    def _dispatch(self, func, args, kwargs):
        flat, _ = tree_flatten((args, kwargs))
        tensors = [t for t in flat if isinstance(t, torch.Tensor)]
        on_dev = [t for t in tensors if isinstance(t, StandInTensor)]
        cpu = [t for t in tensors if not isinstance(t, StandInTensor)]
        name = str(func)
        target = kwargs.get("device")
        to_dev = _is_stand_in_device(target)
        to_host = target is not None and not to_dev and torch.device(target).type == "cpu"

        # factories and copies that name a device
        if func in (aten._to_copy.default,):
            if on_dev and to_host:
                self._sync(".cpu() / .to(cpu)")
        elif func is aten.copy_.default:
            dst, src = args[0], args[1]
            if isinstance(src, StandInTensor) and not isinstance(dst, StandInTensor):
                self._sync("copy_ to the host")
        elif func is aten._pin_memory.default or func is aten.is_pinned.default:
            pass
        elif func in _SYNC_OPS and on_dev:
            self._sync(func.__name__)
        elif func in _INDEX_OPS:
            base, idx = args[0], [i for i in args[1] if i is not None]
            if not isinstance(base, StandInTensor) and any(isinstance(i, StandInTensor) for i in idx):
                if base.ndim > 0:
                    self._breach("CPU tensor indexed with a device index", name, f"base {tuple(base.shape)} on the CPU")
            if isinstance(base, StandInTensor) and any(i.dtype == torch.bool for i in idx):
                self._sync("boolean-mask indexing")
        # the generator rule
        gen = kwargs.get("generator")
        if gen is not None and gen.device.type == "cpu" and (on_dev or to_dev):
            self._breach(
                "CPU torch.Generator on a device op",
                name,
                "pass a generator on the device, or draw on the CPU and move the result",
            )
        # the mixing rule (copies between devices are legal; 0-dim CPU tensors are scalars;
        # a device tensor may be indexed with CPU indices: CUDA moves them)
        if on_dev and func not in _CROSS_DEVICE_OPS:
            if func in _INDEX_OPS:
                exempt = (
                    {id(i) for i in args[1] if i is not None}
                    if isinstance(args[0], StandInTensor)
                    else {id(t) for t in cpu}
                )  # a CPU base with device indices is reported above
            else:
                exempt = set()
            big = [t for t in cpu if t.ndim > 0 and id(t) not in exempt]
            if big:
                self._breach(
                    "mixed devices",
                    name,
                    f"device tensors {[tuple(t.shape) for t in on_dev][:3]} with CPU tensors "
                    f"{[tuple(t.shape) for t in big][:3]}",
                )
        out_on_dev = to_dev or (bool(on_dev) and not to_host and func not in _HOST_RESULT_OPS)
        if func is aten.copy_.default:
            out_on_dev = isinstance(args[0], StandInTensor)
        return self._run(func, args, kwargs, out_on_dev)

    @staticmethod
    def _run(func, args, kwargs, out_on_dev):
        def unwrap(x):
            if isinstance(x, StandInTensor):
                return x.elem
            if isinstance(x, torch.device) and _is_stand_in_device(x):
                return torch.device("cpu")
            return x

        args_, kwargs_ = tree_map(unwrap, args), tree_map(unwrap, kwargs)
        if _is_stand_in_device(kwargs_.get("device")):
            kwargs_["device"] = torch.device("cpu")
        if kwargs_.get("pin_memory"):
            kwargs_["pin_memory"] = False
        out = func(*args_, **kwargs_)
        if out_on_dev is None:  # no check active: results stay wrapped where inputs were
            out_on_dev = any(isinstance(x, StandInTensor) for x in tree_flatten((args, kwargs))[0])
            if (
                func is aten._to_copy.default
                and kwargs.get("device") is not None
                and not _is_stand_in_device(kwargs.get("device"))
            ):
                out_on_dev = False
        if func is aten.copy_.default or (func._schema.is_mutable and func.__name__.endswith("_")):
            # in-place ops return their first argument: give back the caller's object
            if isinstance(args[0], torch.Tensor):
                return args[0]
        if not out_on_dev:
            return out
        return tree_map(
            lambda t: StandInTensor(t) if isinstance(t, torch.Tensor) and not isinstance(t, StandInTensor) else t, out
        )


_CROSS_DEVICE_OPS = {
    aten._to_copy.default,
    aten.copy_.default,
    aten.lift_fresh.default,
    aten._local_scalar_dense.default,
}
_INDEX_OPS = {aten.index.Tensor, aten.index_put_.default, aten.index_put.default, aten._index_put_impl_.default}
_HOST_RESULT_OPS = {aten._local_scalar_dense.default, aten.equal.default, aten.is_nonzero.default}


@contextlib.contextmanager
def _swap_on_conversion():
    old = torch.__future__.get_swap_module_params_on_conversion()
    torch.__future__.set_swap_module_params_on_conversion(True)
    try:
        yield
    finally:
        torch.__future__.set_swap_module_params_on_conversion(old)


def _third_party_patches():
    """Where TorchRL branches on ``device.type == "cuda"``, the stand-in takes CUDA's branch."""
    from torchrl.collectors import _single

    get_sync_fn = _single.Collector._get_sync_fn

    def _get_sync_fn(self, device):
        if device is not None and device.type == STAND_IN_NAME:
            return get_sync_fn(self, None)  # what TorchRL does for a CUDA device: no host-side sync
        return get_sync_fn(self, device)

    def pin_memory(self, device=None):  # page-locked memory needs a real GPU; the stand-in copies from any
        return self

    return [_patched(_single.Collector, "_get_sync_fn", _get_sync_fn), _patched(torch.Tensor, "pin_memory", pin_memory)]


_LIBRARY_ROOTS = tuple(
    {
        os.path.abspath(p) + os.sep
        for p in (
            sysconfig.get_paths()["stdlib"],
            sysconfig.get_paths()["purelib"],
            sysconfig.get_paths()["platlib"],
            os.path.dirname(os.path.dirname(torch.__file__)),
        )
    }
)


def _is_plumbing(path: str) -> bool:
    """torch's own dispatch and module-call frames: never the interesting library line."""
    return any(
        part in path
        for part in (
            os.sep + "torch" + os.sep + "utils" + os.sep,
            os.sep + "_dynamo" + os.sep,
            os.sep + "torch" + os.sep + "_compile.py",
            os.sep + "torch" + os.sep + "nn" + os.sep,
            os.sep + "torch" + os.sep + "_tensor.py",
            os.sep + "pyvers" + os.sep,
            os.sep + "torch" + os.sep + "overrides.py",
        )
    )


def _short(path: str) -> str:
    for root in (os.getcwd() + os.sep,):
        if path.startswith(root):
            return path[len(root) :]
    i = path.find("site-packages" + os.sep)
    return path[i + len("site-packages") + 1 :] if i >= 0 else path


@contextlib.contextmanager
def _patched(obj, name: str, value: Any):
    old = getattr(obj, name)
    setattr(obj, name, value)
    try:
        yield
    finally:
        setattr(obj, name, old)
