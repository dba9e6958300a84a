"""Every setting is validated before anything trains (issue 37): ranges, finiteness,
integer-ness and combinations that cannot work are refused in one line naming the setting;
a finished run is never rewritten by a resume that trains nothing; the unclear cases (an
out_dir that is a file, an unknown env id, a logger whose package is missing, the batched
engine asked to resume) say which setting and what to do."""

from __future__ import annotations

import dataclasses
import math
import os
import re
import subprocess
import sys
import tempfile
import typing
from pathlib import Path

import pytest
import tomllib
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from torchrl_hybrid.families.atari import AtariConfig, atari_config
from torchrl_hybrid.families.gym import GymConfig, config_from_dict, train_gym
from torchrl_hybrid.families.gym_batched import train_taxi_batched
from torchrl_hybrid.trainers import config as run_module
from torchrl_hybrid.trainers.config import LOGGER_PACKAGES, LOGGERS
from torchrl_hybrid.utils.config import merge_dicts
from torchrl_hybrid.utils.files import RUN_FILES

ROOT = Path(__file__).resolve().parents[1]
# 4 envs x 2 steps = 8 frames a batch: a run of 64 frames is 8 updates, a few seconds with its evaluations
# (Taxi's expert ends every episode within 30 steps)
SMALL = {
    "total_frames": 64,
    "device": "cpu",
    "env": {"num_envs": 4, "max_episode_steps": 30},
    "logger": {"log_every_frames": 64, "eval_episodes": 2, "final_eval_episodes": 2, "progress_bar": False},
}


def small(out: Path, **groups) -> GymConfig:
    return config_from_dict(merge_dicts(SMALL, {"out_dir": str(out), **groups}))


def numeric_settings(cls, prefix: str = "") -> list[str]:
    """The dotted names of every int and float setting of a config schema (optional ones too)."""
    names, hints = [], typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        sub = f.default_factory if f.default_factory is not dataclasses.MISSING else None
        if sub is not None and dataclasses.is_dataclass(sub):
            names += numeric_settings(sub, f"{prefix}{f.name}.")
            continue
        kinds = set(typing.get_args(hints[f.name])) - {type(None)} or {hints[f.name]}
        if kinds <= {int, float}:
            names.append(prefix + f.name)
    return names


def nested(name: str, value) -> dict:
    d: dict = {}
    *head, last = name.split(".")
    node = d
    for h in head:
        node = node.setdefault(h, {})
    node[last] = value
    return d


def assert_names(err: Exception, name: str) -> None:
    """A refusal is one line and names the setting (not as part of a longer name)."""
    msg = str(err)
    assert "\n" not in msg, msg
    assert re.search(rf"(?<![\w.]){re.escape(name)}(?![\w])", msg), f"{name}: {msg}"


TAXI_NUMERIC = numeric_settings(GymConfig)
ATARI_NUMERIC = numeric_settings(AtariConfig)
ANY_NUMBER = st.one_of(
    st.sampled_from(
        [
            0,
            -1,
            1,
            2,
            -0.0,
            0.5,
            1.5,
            True,
            math.nan,
            math.inf,
            -math.inf,
            1e300,
            -1e300,
            10**30,
            -(10**30),
            2**63,
            1e-320,
        ]
    ),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
)


def test_the_schemas_numeric_settings_are_the_ones_the_property_tests_draw():
    for name in (
        "seed",
        "total_frames",
        "loss.bc_coeff",
        "demo.batch_size",
        "optim.lr",
        "optim.warmup_frames",
        "env.num_envs",
        "logger.eval_episodes",
        "ppo.clip_epsilon",
        "collector.worker_gpus",
        "encoder.hidden",
    ):
        assert name in TAXI_NUMERIC
    for name in ("env.noop_max", "collector.env_groups", "logger.accuracy_pairs", "loss.bc_start_frames"):
        assert name in ATARI_NUMERIC


@settings(max_examples=1000, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_any_value_of_any_numeric_setting_passes_or_is_refused_naming_it(data):
    """Every numeric setting of every family (gymnasium, which the batched engine shares, and
    Atari): random values, NaN, infinities, negatives, zero and huge ones either pass
    validation or are refused with a one-line ValueError that names the setting."""
    family = data.draw(st.sampled_from(["taxi", "atari"]))
    name = data.draw(st.sampled_from(TAXI_NUMERIC if family == "taxi" else ATARI_NUMERIC))
    value = data.draw(ANY_NUMBER)
    base = (
        data.draw(st.sampled_from([{}, {"rl": "ppo"}, {"engine": "batched"}]))
        if family == "taxi"
        else {"variant": "a2c"}
    )
    build = config_from_dict if family == "taxi" else atari_config
    try:
        build(merge_dicts(base, nested(name, value))).validate()
    except ValueError as err:
        assert_names(err, name)
        return
    # what passed is a value the setting can take
    if isinstance(value, float):
        assert math.isfinite(value), (name, value)
    assert not isinstance(value, bool), (name, value)
    if name.endswith(("frames", "episodes", "envs", "size", "steps", "layers", "workers")):
        assert value >= 0, (name, value)


# values that cannot make a run long: small integers, and floats from the awkward ones to the plain ones
CHEAP_NUMBER = st.one_of(
    st.integers(min_value=-2, max_value=12),
    st.sampled_from([math.nan, math.inf, -math.inf, -0.5, 0.0, 1e-8, 0.3, 0.99, 1.0, 3.0, 1e5, 1e300]),
)
SMALL_NETS = {"d": 16, "d_state": 16, "identity_embedding": False}  # a few seconds a run on a busy CPU
RUN_SETTINGS = [n for n in TAXI_NUMERIC if n not in ("threads",)]  # threads: the recipes' process setting


@settings(
    max_examples=8,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)
@given(
    name=st.sampled_from(RUN_SETTINGS),
    value=CHEAP_NUMBER,
    base=st.sampled_from(
        [
            {"engine": "torchrl"},
            {"engine": "torchrl", "rl": "ppo", "ppo": {"epochs": 1, "minibatches": 2}},
            {"engine": "batched"},
        ]
    ),
)
def test_a_taxi_run_with_a_value_that_passes_validation_works(name, value, base):
    """A sample of the values that pass validation train a 64-frame Taxi run without error;
    the rest are refused before anything is built, naming the setting. A value that only the
    env can judge (episodes too short for the built-in expert) is refused while building,
    also in one line naming it."""
    with tempfile.TemporaryDirectory() as tmp:
        d = merge_dicts(
            merge_dicts(SMALL, {"out_dir": f"{tmp}/run", "demo": {"rho": "uniform"}, **SMALL_NETS, **base}),
            nested(name, value),
        )
        try:
            cfg = config_from_dict(d).validate()
        except ValueError as err:
            assert_names(err, name)
            assert not Path(tmp, "run").exists()  # refused before out_dir was made
            assume(False)  # not a run: hypothesis draws another example (max_examples counts the runs)
        try:
            if cfg.engine == "batched":
                summary = train_taxi_batched([cfg], plot=False)[0]
            else:
                summary = train_gym(cfg)
        except ValueError as err:  # the env's own limits, e.g. the expert needs longer episodes
            assert_names(err, name)
            return
        assert summary["frames"] >= cfg.total_frames and math.isfinite(summary["final_return"])


@pytest.mark.parametrize(
    "groups,name",
    [
        ({"loss": {"bc_coeff": math.nan}}, "loss.bc_coeff"),
        ({"loss": {"bc_coeff": math.inf}}, "loss.bc_coeff"),
        ({"optim": {"lr": math.nan}}, "optim.lr"),
        ({"optim": {"eps": -1.0}}, "optim.eps"),
        ({"demo": {"batch_size": -4, "rho": "uniform"}}, "demo.batch_size"),
        ({"seed": -1}, "seed"),
        ({"loss": {"gamma": 0.0}}, "loss.gamma"),
    ],
)
def test_known_bad_values_are_refused_before_training(tmp_path, groups, name):
    """nan/inf loss weights used to fail after training started (NaN probabilities), a negative
    demo batch with a negative-dimension RuntimeError, a negative eps in torch's RMSprop; a
    discount below 1e-7 in TorchRL's return estimator (IndexError) (found by the property test
    below). PPO minibatches of explorer transitions only, found the same way, are handled by the
    loss (tests/test_objectives.py)."""
    with pytest.raises(ValueError) as err:
        train_gym(small(tmp_path / "run", **groups))
    assert_names(err.value, name)
    assert not (tmp_path / "run").exists()


def test_a_zero_demo_batch_is_refused_for_a_variant_that_clones_the_expert(tmp_path):
    """demo.batch_size=0 with rho=uniform used to turn BC off silently (the hybrid ran as plain A2C)."""
    with pytest.raises(
        ValueError,
        match=r"demo.batch_size=0: variant hybrid_dual clones the expert .* must be >= 1 "
        r"\(variant=a2c trains without demos\)",
    ):
        train_gym(small(tmp_path / "run", demo={"batch_size": 0, "rho": "uniform"}))
    small(tmp_path / "a2c", variant="a2c", demo={"batch_size": 0}).validate()  # no demos: nothing to refuse
    with pytest.raises(ValueError, match="demo.batch_size=0: variant hybrid_dual"):
        atari_config({"demo": {"batch_size": 0, "path": "demos/pong"}}).validate()


def test_ints_and_bools_must_have_their_type_even_when_set_on_the_object():
    cfg = GymConfig()
    cfg.total_frames = 640.5
    with pytest.raises(ValueError, match=r"total_frames=640.5 must be an integer"):
        cfg.validate()
    cfg = GymConfig()
    cfg.loss.n_steps = 2.0
    with pytest.raises(ValueError, match=r"loss.n_steps=2.0 must be an integer"):
        cfg.validate()
    cfg = AtariConfig(variant="a2c")
    cfg.logger.progress_bar = "yes"
    with pytest.raises(ValueError, match=r"logger.progress_bar='yes' must be true or false"):
        cfg.validate()


def _snapshot(out: Path) -> dict[str, tuple[int, bytes]]:
    files = [
        p
        for f in RUN_FILES
        for p in ([out / f] if (out / f).is_file() else sorted((out / f).rglob("*")))
        if p.is_file()
    ]
    return {str(p.relative_to(out)): (p.stat().st_mtime_ns, p.read_bytes()) for p in files}


def test_resume_of_a_finished_run_that_total_frames_does_not_extend_is_refused_and_touches_nothing(tmp_path):
    """It used to exit 0 and rewrite summary.json and model.pt (train_time_s 0.0, the config
    saying fewer frames than the run did)."""
    out = tmp_path / "run"
    train_gym(small(out))
    before = _snapshot(out)
    assert {"summary.json", "model.pt", "config.json", "metrics.csv"} <= set(before)
    for total in (64, 32):
        with pytest.raises(
            ValueError,
            match=rf"the run in {re.escape(str(out))} is already at 64 frames; raise "
            rf"total_frames \(now {total}\) to train further",
        ):
            train_gym(small(out, total_frames=total, resume=True))
    assert _snapshot(out) == before
    # the same checkpoint without its summary (a run stopped after its last checkpoint): refused when loaded
    (out / "summary.json").unlink()
    del before["summary.json"]
    with pytest.raises(ValueError, match="is already at 64 frames; raise total_frames"):
        train_gym(small(out, total_frames=64, resume=True))
    assert _snapshot(out) == before
    # raising total_frames trains further, as before
    assert train_gym(small(out, total_frames=96, resume=True))["resumed_from_frames"] == 64


def _recipe(name: str):
    sys.path.insert(0, str(ROOT / "recipes"))
    try:
        import importlib

        return importlib.import_module(name)
    finally:
        sys.path.remove(str(ROOT / "recipes"))


def test_batched_engine_asked_to_resume_names_the_setting(tmp_path, capsys):
    """It used to say 'pass ... resume=true to continue it' (out_dir was checked before the settings)."""
    from omegaconf import OmegaConf

    taxi = _recipe("taxi")
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("{}")  # a finished run there
    cfg = OmegaConf.create(dataclasses.asdict(small(out, engine="batched", resume=True)))
    with pytest.raises(SystemExit) as exit_:
        taxi.run(cfg)
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and err.count("\n") == 0
    assert err.startswith("error: resume=true needs engine=torchrl") and "drop resume=true" in err


def test_an_out_dir_that_is_a_file_is_refused_in_one_line_before_hydra(tmp_path):
    """It used to end in Hydra's FileExistsError traceback (hydra.run.dir is ${out_dir})."""
    f = tmp_path / "afile"
    f.write_text("not a folder")
    res = subprocess.run(
        [sys.executable, str(ROOT / "recipes" / "train.py"), f"out_dir={f}", "total_frames=64"],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert res.returncode == 2, res.stderr[-2000:]
    assert (
        res.stderr.strip()
        == f"error: out_dir={f} is a file, not a folder; choose another out_dir (or move the file away)"
    )
    assert f.read_text() == "not a folder"
    train = _recipe("train")
    for argv, bad in ([f"++out_dir='{f}/run'"], f"{f}/run"), ([f"hydra.run.dir={f}"], str(f)):
        with pytest.raises(SystemExit):
            train.check_out_dir(argv)
        assert train.out_dir_from_overrides(argv) == bad
    train.check_out_dir(["out_dir=outputs/x/${now:%H}", "seed=1"])  # interpolations are Hydra's to resolve
    with pytest.raises(ValueError, match="is inside .*afile, which is a file"):  # the library says the same
        train_gym(small(f / "run"))


def test_an_unknown_env_id_is_refused_naming_the_setting(tmp_path):
    """It used to be gymnasium's NameNotFound traceback."""
    with pytest.raises(ValueError, match=r"env.env_id=NoSuchEnv-v0: Environment `NoSuchEnv` doesn't exist\.") as err:
        train_gym(small(tmp_path / "run", env={"env_id": "NoSuchEnv-v0"}))
    assert_names(err.value, "env.env_id")
    with pytest.raises(ValueError, match=r"env.env_id=Taxi-v9: .*doesn't exist"):
        config_from_dict({"env": {"env_id": "Taxi-v9"}}).validate()
    # what only gym.make can judge (a module to import, keyword arguments) is re-said at env creation
    with pytest.raises(ValueError, match=r"env.env_id=nosuchmodule:Foo-v0 .*gymnasium cannot make it") as err:
        train_gym(small(tmp_path / "mod", env={"env_id": "nosuchmodule:Foo-v0"}))
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match=r"env.kwargs=\{'nope': 1\}: gymnasium cannot make it .*unexpected keyword"):
        train_gym(small(tmp_path / "kw", env={"kwargs": {"nope": 1}}))


def test_every_logger_package_is_an_extra_that_make_test_installs():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert set(LOGGER_PACKAGES) <= set(LOGGERS)
    for package in LOGGER_PACKAGES.values():
        assert extras[package] == [package]
    assert "hypothesis" in extras["test"]
    assert '".[test,lint,docs,tensorboard]"' in (ROOT / "Makefile").read_text()


@pytest.mark.parametrize("backend", LOGGERS)
def test_each_logger_backend_runs_or_says_which_extra_to_install(tmp_path, backend, monkeypatch):
    package = LOGGER_PACKAGES.get(backend)
    if package is not None:  # a missing package: the extra to install, before anything is built
        monkeypatch.setattr(run_module, "_has_package", lambda name: name != package)
        with pytest.raises(
            ValueError,
            match=rf"logger.backend={backend} needs the {package} package, which is not "
            rf"installed: pip install -e '\.\[{package}\]'",
        ):
            train_gym(small(tmp_path / "missing", logger={"backend": backend}))
        assert not (tmp_path / "missing").exists()
        monkeypatch.undo()
        pytest.importorskip(package)
    if backend == "wandb":
        monkeypatch.setenv("WANDB_MODE", "offline")
    out = tmp_path / "run"
    summary = train_gym(small(out, logger={"backend": backend}))
    assert summary["frames"] == 64 and (out / "metrics.csv").exists()
    logged = [p.name for p in (out / "logs").rglob("*") if p.is_file()] if (out / "logs").exists() else []
    if backend == "none":
        assert not logged
    elif backend == "tensorboard":
        assert any(n.startswith("events.out.tfevents") for n in logged), logged
    elif backend == "csv":
        assert any(n.endswith(".csv") for n in logged), logged
