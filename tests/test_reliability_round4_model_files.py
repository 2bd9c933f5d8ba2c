"""Model files from strangers: a policy .zip or .pt is read without unpickling anything.

Issue 51, item 5 (a model zip ran code on load), item 16 (crafted .pt files gave KeyError
tracebacks), a .pt flown outside its operating range (no warning) and SB3's logger
folders left in the system temp directory.
"""

from __future__ import annotations

import base64
import io
import json
import pickle
import tempfile
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
torch = pytest.importorskip("torch")

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from agents.marl_torchrl import POLICY_FORMAT, TorchRLPolicy  # noqa: E402
from agents.policy import (  # noqa: E402
    OutsideOperatingRangeWarning,
    SB3AgentPolicy,
    compiled_forward,
    load_model,
    read_meta,
)
from atc_nf_env import cli  # noqa: E402
from atc_nf_env.envs.observations import ObservationSpec  # noqa: E402
from atc_nf_env.episode import run_episode  # noqa: E402
from atc_nf_env.evaluate import Study, evaluate  # noqa: E402
from atc_nf_env.policy import make_policy  # noqa: E402

MODELS = Path(__file__).resolve().parents[1] / "agents" / "models"
SHIPPED = sorted(MODELS.glob("*.zip"))
SHORT_S = 600.0


class _WritesMarker:
    """Unpickling this writes ``path``: what a hostile model file would do instead."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        return exec, (f"open({self.path!r}, 'w').write('code ran')",)


def _rezip(source: Path, target: Path, replace: dict[str, bytes]) -> Path:
    """A copy of the zip ``source`` with the entries of ``replace`` put in (or added)."""
    with zipfile.ZipFile(source) as original, zipfile.ZipFile(target, "w") as copy:
        for name in original.namelist():
            copy.writestr(name, replace.get(name, original.read(name)))
        for name, content in replace.items():
            if name not in original.namelist():
                copy.writestr(name, content)
    return target


def _data(source: Path) -> dict[str, Any]:
    with zipfile.ZipFile(source) as archive:
        return json.loads(archive.read("data"))


def _with_data(source: Path, target: Path, data: dict[str, Any]) -> Path:
    return _rezip(source, target, {"data": json.dumps(data).encode()})


def _evil_data_zip(tmp_path: Path, marker: Path) -> Path:
    """The shipped ``imitation_bc.zip`` with one extra ``:serialized:`` key whose payload
    writes ``marker``, and the same payload in place of its pickled observation space."""
    data = _data(MODELS / "imitation_bc.zip")
    payload = base64.b64encode(pickle.dumps(_WritesMarker(marker))).decode()
    data["evil"] = {":type:": "<class 'dict'>", ":serialized:": payload}
    data["observation_space"] = {**data["observation_space"], ":serialized:": payload}
    return _with_data(MODELS / "imitation_bc.zip", tmp_path / "imitation_bc.zip", data)


def _evil_weights_zip(tmp_path: Path, marker: Path) -> Path:
    """The shipped ``imitation_bc.zip`` whose ``policy.pth`` (and optimizer state) holds,
    beside the real tensors, an object whose unpickling writes ``marker``."""
    with zipfile.ZipFile(MODELS / "imitation_bc.zip") as archive:
        state = torch.load(io.BytesIO(archive.read("policy.pth")), weights_only=True)
    buffer = io.BytesIO()
    torch.save({**state, "evil": _WritesMarker(marker)}, buffer)
    return _rezip(MODELS / "imitation_bc.zip", tmp_path / "evil_weights.zip",
                  {"policy.pth": buffer.getvalue(), "policy.optimizer.pth": buffer.getvalue()})


@pytest.fixture
def marker(tmp_path: Path) -> Path:
    return tmp_path / "code-ran.txt"


# ------------------------------------------------------------------ the attack is real


def test_the_crafted_files_do_run_code_under_sb3_and_torch_defaults(tmp_path: Path, marker: Path) -> None:
    """The yardstick: SB3's own loader and an unrestricted ``torch.load`` run the payloads
    (what ``agents.policy`` called before), so the tests below that see no marker mean something."""
    from stable_baselines3.common.save_util import load_from_zip_file

    load_from_zip_file(str(_evil_data_zip(tmp_path, marker)), load_data=True)
    assert marker.read_text() == "code ran"
    marker.unlink()
    with zipfile.ZipFile(_evil_weights_zip(tmp_path, marker)) as archive:
        torch.load(io.BytesIO(archive.read("policy.pth")), weights_only=False)
    assert marker.read_text() == "code ran"


# ------------------------------------------------------------------ every entry point


def test_a_pickle_in_the_data_is_never_unpickled_by_the_loaders(tmp_path: Path, marker: Path) -> None:
    evil = _evil_data_zip(tmp_path, marker)
    assert read_meta(evil)["training"]["stage"] == "bc"
    assert not marker.exists()
    policy = make_policy(str(evil))
    assert isinstance(policy, SB3AgentPolicy) and not marker.exists()
    shipped = SB3AgentPolicy(MODELS / "imitation_bc.zip")
    obs = np.random.default_rng(5).uniform(-1, 1, (9, policy.model.observation_space.shape[0])).astype(np.float32)
    assert np.array_equal(policy.actions(obs), shipped.actions(obs))  # the weights load, safely


def test_a_pickle_in_the_data_is_never_unpickled_by_the_commands(tmp_path: Path, marker: Path) -> None:
    evil = _evil_data_zip(tmp_path, marker)
    summary = tmp_path / "fly.json"
    assert cli.main(["fly", "--policy", str(evil), "--scenario", "converging-4", "--max-minutes", "10",
                     "--summary-json", str(summary)]) == 0
    assert json.loads(summary.read_text())["runs"] == 1 and not marker.exists()
    out = tmp_path / "runs.jsonl"
    study = Study(policy=str(evil), scenario="converging-4", max_time_s=SHORT_S)
    assert evaluate(study, 2, workers=2, out=out, progress=False)["runs"] == 2  # loads in worker processes
    assert not marker.exists()
    assert cli.main(["benchmark", "--policy", str(evil), "--task", "converging-4", "--split", "validation",
                     "--runs", "1", "--no-reference", "--workers", "1", "--no-progress"]) == 0
    assert not marker.exists()


def test_a_pickle_in_the_weights_is_refused_by_every_entry_point(tmp_path: Path, marker: Path,
                                                                 capsys: pytest.CaptureFixture) -> None:
    evil = _evil_weights_zip(tmp_path, marker)
    with pytest.raises(ValueError, match=r"evil_weights\.zip: its weights cannot be read as plain tensors "
                                         r"\(UnpicklingError: .*Unsupported global.*\); a policy\.pth that needs "
                                         r"unpickling is refused"):
        make_policy(str(evil))
    assert not marker.exists()
    capsys.readouterr()
    assert cli.main(["fly", "--policy", str(evil), "--scenario", "converging-4", "--max-minutes", "10"]) != 0
    error = capsys.readouterr().err.strip()
    assert "cannot be read as plain tensors" in error and "Traceback" not in error and len(error.splitlines()) == 1
    with pytest.raises(ValueError, match="cannot be read as plain tensors"):  # the study loads it first
        evaluate(Study(policy=str(evil), scenario="converging-4", max_time_s=SHORT_S), 2, workers=2,
                 out=tmp_path / "runs.jsonl", progress=False)
    assert read_meta(evil)["algo"] == "ppo"  # the metadata needs no weights
    assert not marker.exists()


def test_training_from_a_strangers_zip_never_unpickles_it(tmp_path: Path, marker: Path,
                                                         capsys: pytest.CaptureFixture) -> None:
    tiny = ["--total-timesteps", "32", "--num-envs", "1", "--n-steps", "16", "--batch-size", "16",
            "--no-progress", "--scenario", "converging-4"]
    out = tmp_path / "from-evil-data"
    assert cli.main(["train", "--out", str(out), "--init-from", str(_evil_data_zip(tmp_path, marker)), *tiny]) == 0
    assert (out / "model.zip").is_file() and not marker.exists()
    capsys.readouterr()
    assert cli.main(["train", "--out", str(tmp_path / "from-evil-weights"), "--init-from",
                     str(_evil_weights_zip(tmp_path, marker)), *tiny]) == 2
    assert "cannot be read as plain tensors" in capsys.readouterr().err and not marker.exists()


def test_a_pickle_in_a_torchrl_policy_file_is_refused(tmp_path: Path, marker: Path) -> None:
    path = tmp_path / "policy.pt"
    torch.save({**_torchrl_header(), "evil": _WritesMarker(marker)}, path)
    with pytest.raises(ValueError, match=r"policy\.pt: not a policy written by agents\.marl_torchrl\.train"):
        make_policy(str(path))
    assert not marker.exists()


# ------------------------------------------------------------------ the shipped models fly as before


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_models_load_as_sb3s_own_loader_loads_them_bit_for_bit(path: Path) -> None:
    from stable_baselines3 import PPO

    ours, meta = load_model(path)
    theirs = PPO.load(str(path), device="cpu")  # trusted: the repository's own files
    mine, reference = ours.policy.state_dict(), theirs.policy.state_dict()
    assert list(mine) == list(reference) and all(torch.equal(mine[k], reference[k]) for k in mine)
    assert type(ours.policy) is type(theirs.policy)
    assert type(ours.policy.features_extractor) is type(theirs.policy.features_extractor)
    assert ours.observation_space == theirs.observation_space and ours.action_space == theirs.action_space
    obs = np.random.default_rng(1).uniform(-1, 1, (32, *ours.observation_space.shape)).astype(np.float32)
    assert np.array_equal(ours.predict(obs, deterministic=True)[0], theirs.predict(obs, deterministic=True)[0])
    assert np.array_equal(compiled_forward(ours)(obs), compiled_forward(theirs)(obs))
    policy = SB3AgentPolicy(path, outside_range="ignore")
    from atc_nf_env.config import SimConfig
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.simulation import WorldView, initial_state

    scenario = make_scenario("converging-4", seed=3)
    policy.reset(scenario, SimConfig())
    view = WorldView(time_s=300.0, state=initial_state(scenario)[0], scenario=scenario)
    flown = policy.observe(view)
    assert np.array_equal(policy.actions(flown), compiled_forward(theirs)(flown))


# ------------------------------------------------------------------ hostile zips


def _edited(tmp_path: Path, name: str, edit: Any) -> Path:
    data = _data(MODELS / "finetuned_ppo.zip")
    edit(data)
    return _with_data(MODELS / "finetuned_ppo.zip", tmp_path / f"{name}.zip", data)


def test_hostile_settings_are_refused_saying_what_is_wrong(tmp_path: Path) -> None:
    def kwargs(**changes: Any) -> Any:
        return lambda data: data["policy_kwargs"].update(changes)

    cases = {
        "activation": (kwargs(activation_fn="<class 'os.system'>"),
                       r"policy_kwargs\['activation_fn'\] = \"<class 'os.system'>\"; allowed: <class 'torch.nn"),
        "unknown": (kwargs(lr_override=3), r"setting 'lr_override', unknown here; allowed: net_arch"),
        "arch": (kwargs(net_arch={"pi": [64, -1]}), r"policy_kwargs\['net_arch'\] .* must be a list of layer widths"),
        "huge": (kwargs(net_arch={"pi": [2**30], "vf": [64]}),
                 r"describe a policy of at least \d+ parameters, but its policy\.pth holds \d+"),
        "space": (lambda data: data["observation_space"].update(_shape=[29]),
                  r"observations of shape \(29,\) and actions of shape \(2,\) do not fit a shared model with K = 4"),
        "dtype": (lambda data: data["action_space"].update(dtype="float64"), r"action_space is not a float32"),
        "class": (lambda data: data["policy_class"].update(__init__="<function Evil.__init__ at 0x1>"),
                  r"another algorithm \(Evil: neither PPO nor SAC\)"),
        "no class": (lambda data: data.pop("policy_class"), r"its policy class cannot be read"),
        "meta": (lambda data: data.update(atc_nf_meta={":serialized:": "gASVAAAAAAAAAAA=", ":type:": "dict"}),
                 r"its atc_nf_meta is a pickled object, which is never unpickled here"),
        "env": (lambda data: data["atc_nf_meta"].update(env=[1, 2]), r"atc_nf_meta\['env'\] = \[1, 2\]: must be a"),
        "neighbours": (lambda data: data["atc_nf_meta"]["env"].update(n_neighbours=10**9),
                       r"n_neighbours'\] = 1000000000: must be an integer in \[0, 1024\]"),
    }
    for name, (edit, said) in cases.items():
        path = _edited(tmp_path, name, edit)
        with pytest.raises(ValueError, match=rf"{name}\.zip: .*{said}"):
            make_policy(str(path))


def test_weights_that_do_not_fit_or_are_not_finite_are_refused(tmp_path: Path) -> None:
    with zipfile.ZipFile(MODELS / "imitation_bc.zip") as archive:
        state = torch.load(io.BytesIO(archive.read("policy.pth")), weights_only=True)
    variants = {"missing": {k: v for k, v in state.items() if k != "action_net.bias"},
                "nan": {**state, "action_net.bias": torch.full_like(state["action_net.bias"], float("nan"))},
                "list": [1, 2, 3]}
    said = {"missing": r"cannot be loaded as a PPO model \(RuntimeError: Error\(s\) in loading state_dict",
            "nan": r"holds NaN or inf in 'action_net.bias'", "list": r"is not a state dict of named tensors"}
    for name, weights in variants.items():
        buffer = io.BytesIO()
        torch.save(weights, buffer)
        path = _rezip(MODELS / "imitation_bc.zip", tmp_path / f"{name}.zip", {"policy.pth": buffer.getvalue()})
        with pytest.raises(ValueError, match=rf"{name}\.zip: .*{said[name]}"):
            make_policy(str(path))


_JSON = st.recursive(st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=False)
                     | st.text(max_size=12), lambda inner: st.lists(inner, max_size=3)
                     | st.dictionaries(st.text(max_size=6), inner, max_size=3), max_leaves=6)
_FIELDS = [("policy_kwargs",), ("policy_kwargs", "net_arch"), ("policy_kwargs", "activation_fn"),
           ("observation_space", "_shape"), ("action_space", "_shape"), ("policy_class", "__init__"),
           ("atc_nf_meta", "env"), ("atc_nf_meta", "env", "n_neighbours"), ("atc_nf_meta", "mode"), ("use_sde",)]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(field=st.sampled_from(_FIELDS), value=_JSON)
def test_any_json_in_the_settings_loads_or_is_refused_with_a_value_error(tmp_path: Path, field: tuple[str, ...],
                                                                         value: Any) -> None:
    data = _data(MODELS / "finetuned_ppo.zip")
    target = data
    for key in field[:-1]:
        target = target[key]
    target[field[-1]] = value
    path = _with_data(MODELS / "finetuned_ppo.zip", tmp_path / "fuzzed.zip", data)
    try:
        SB3AgentPolicy(path)
    except ValueError as error:
        assert "fuzzed.zip" in str(error)


# ------------------------------------------------------------------ TorchRL policy files (item 16)


def _torchrl_header(hidden: int = 16, task: str = "converging-4") -> dict[str, Any]:
    """A policy file as ``agents.marl_torchrl.train`` writes one (random weights)."""
    generator = torch.Generator().manual_seed(0)
    dim = ObservationSpec(n_neighbours=4).dim
    shapes = [(hidden, dim), (hidden, hidden), (2, hidden)]
    return {
        "format": POLICY_FORMAT, "algorithm": "mappo", "task": task, "seed": 0, "frames": 128,
        "layers": [{"weight": torch.randn(*shape, generator=generator) * 0.3, "bias": torch.zeros(shape[0]),
                    "activation": activation} for shape, activation in zip(shapes, ("tanh", "tanh", "identity"))],
        "output": "tanh",
        "env": {"n_neighbours": 4, "max_episode_minutes": 180.0,
                "action_mapping": {"distance_nm": 100.0, "distance_span_nm": 40.0, "angle_span_deg": 90.0},
                "observation_dim": dim},
        "actor_state_dict": {},
    }


def _saved(tmp_path: Path, header: dict[str, Any], name: str = "policy.pt") -> Path:
    path = tmp_path / name
    torch.save(header, path)
    return path


def test_a_well_formed_torchrl_file_flies(tmp_path: Path) -> None:
    policy = TorchRLPolicy(_saved(tmp_path, _torchrl_header()))
    result = run_episode(policy, "converging-4", seed=2, max_time_s=SHORT_S)
    assert result.metrics.n_aircraft == 4


def test_torchrl_files_lacking_a_key_say_which(tmp_path: Path) -> None:
    for key in ("algorithm", "task", "layers", "output", "env"):
        header = _torchrl_header()
        del header[key]
        with pytest.raises(ValueError, match=rf"policy\.pt: the policy file lacks '{key}'"):
            TorchRLPolicy(_saved(tmp_path, header))
    for key in ("n_neighbours", "max_episode_minutes", "action_mapping"):
        header = _torchrl_header()
        del header["env"][key]
        with pytest.raises(ValueError, match=rf"policy\.pt: the policy file lacks env\.'{key}'"):
            TorchRLPolicy(_saved(tmp_path, header))
    for key in ("weight", "bias", "activation"):
        header = _torchrl_header()
        del header["layers"][1][key]
        with pytest.raises(ValueError, match=rf"policy\.pt: the policy file lacks layers\[1\]\.'{key}'"):
            TorchRLPolicy(_saved(tmp_path, header))


def test_torchrl_files_with_wrong_values_say_what_is_allowed(tmp_path: Path) -> None:
    def edited(edit: Any) -> dict[str, Any]:
        header = _torchrl_header()
        edit(header)
        return header

    cases = [
        (lambda h: h["layers"][0].update(activation="relu"), r"layers\[0\]\.activation = 'relu': allowed: identity, tanh"),
        (lambda h: h.update(layers=[]), r"'layers' = list of length 0: must be a list of 1 to 64 layers"),
        (lambda h: h["layers"][1].update(weight=torch.zeros(16, 7)), r"layers\[1\]\.weight takes 7 inputs, but layers\[0\] gives 16"),
        (lambda h: h["layers"][2].update(weight=torch.zeros(3, 16), bias=torch.zeros(3)), r"last layer gives 3 values; the action has 2"),
        (lambda h: h["layers"][0].update(bias=torch.zeros(5)), r"layers\[0\]\.bias = a torch.float32 tensor of shape \(5,\): must be a 1-D float tensor of 16"),
        (lambda h: h["layers"][0].update(weight=torch.full((16, 28), float("nan"))), r"layers\[0\] holds NaN or inf"),
        (lambda h: h.update(output="sigmoid"), r"output = 'sigmoid': allowed: tanh"),
        (lambda h: h.update(algorithm="dqn"), r"algorithm = 'dqn': allowed: ippo, mappo"),
        (lambda h: h.update(task="nowhere"), r"its task = 'nowhere': the .* suite has converging-4"),
        (lambda h: h["env"].update(n_neighbours=-1), r"env\.n_neighbours = -1: must be an integer in \[0, 4096\]"),
        (lambda h: h["env"].update(max_episode_minutes=float("nan")), r"its env: ValueError: max_episode_minutes"),
        (lambda h: h["env"].update(action_mapping={"bogus": 1}), r"its env: ValueError: action_mapping: unknown fields"),
    ]
    for edit, said in cases:
        with pytest.raises(ValueError, match=rf"policy\.pt: .*{said}"):
            TorchRLPolicy(_saved(tmp_path, edited(edit)))


_VALUES = (st.none() | st.booleans() | st.integers(-5, 5) | st.floats() | st.text(max_size=8)
           | st.sampled_from(["tanh", "identity", "relu", "ippo", "converging-4"])
           | st.builds(lambda shape: torch.zeros(tuple(shape)), st.lists(st.integers(0, 30), max_size=3))
           | st.lists(st.none(), max_size=2) | st.dictionaries(st.text(max_size=4), st.integers(), max_size=2))
_HEADER_FIELDS = [("algorithm",), ("task",), ("output",), ("layers",), ("env",), ("env", "n_neighbours"),
                  ("env", "max_episode_minutes"), ("env", "action_mapping"), ("layers", 0),
                  ("layers", 0, "weight"), ("layers", 1, "bias"), ("layers", 2, "activation")]


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fields=st.lists(st.tuples(st.sampled_from(_HEADER_FIELDS), _VALUES | st.just(KeyError)), min_size=1,
                       max_size=3))
def test_fuzzed_torchrl_headers_load_or_raise_a_value_error_naming_the_file(tmp_path: Path, fields: list) -> None:
    header = _torchrl_header()
    for field, value in fields:
        target: Any = header
        try:
            for key in field[:-1]:
                target = target[key] if isinstance(target, (dict, list)) else None
            if not isinstance(target, (dict, list)):
                continue  # an earlier change replaced the container
            if value is KeyError:
                del target[field[-1]]
            else:
                target[field[-1]] = value
        except (KeyError, IndexError, TypeError):
            continue  # an earlier change removed or replaced the container
    path = _saved(tmp_path, header)
    try:
        TorchRLPolicy(path)
    except ValueError as error:
        assert str(path) in str(error)


def test_a_torchrl_policy_outside_its_training_task_warns_once_or_refuses(tmp_path: Path) -> None:
    path = _saved(tmp_path, _torchrl_header(task="converging-4"), "outside.pt")
    policy = TorchRLPolicy(path)
    assert policy.operating_range == {"n_aircraft": [4, 4], "wind_sigma_mps": [pytest.approx(5.17, abs=0.01)] * 2}
    with pytest.warns(OutsideOperatingRangeWarning, match=r"outside\.pt flies outside its operating range: 6 "
                                                          r"aircraft \(trained on 4\.\.4\).*task 'converging-4'"):
        run_episode(policy, "converging-6", seed=1, max_time_s=SHORT_S)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per model and process
        run_episode(policy, "converging-6", seed=2, max_time_s=SHORT_S)
        run_episode(TorchRLPolicy(_saved(tmp_path, _torchrl_header(), "inside.pt")), "converging-4", seed=2,
                    max_time_s=SHORT_S)
    with pytest.raises(ValueError, match=r"wind sigma 9 m/s \(trained on 5\.17\.\.5\.17\)"):
        run_episode(TorchRLPolicy(path, outside_range="refuse"), "converging-4", seed=1, wind_sigma_mps=9.0)
    with pytest.raises(ValueError, match=r"outside_range = 'loud': allowed: warn, refuse, ignore"):
        TorchRLPolicy(path, outside_range="loud")


# ------------------------------------------------------------------ SB3's logger folders


def test_sb3_training_in_tests_logs_under_pytests_temp_folder(tmp_path_factory: pytest.TempPathFactory) -> None:
    from stable_baselines3 import PPO

    from atc_nf_env.envs.vector import make_sb3_vec_env

    model = PPO("MlpPolicy", make_sb3_vec_env(1, mode="shared", scenario="converging-3"), n_steps=16,
                batch_size=16, n_epochs=1, device="cpu")
    model.learn(16)
    folder = Path(model.logger.get_dir()).resolve()
    assert folder.is_relative_to(tmp_path_factory.getbasetemp().resolve()), folder
    assert folder.parent != Path(tempfile.gettempdir()).resolve()
