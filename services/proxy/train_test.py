"""Training a proxy end to end on real (short) recordings: the numpy proxy's probs are the torch
network's floored factored softmax exactly, it plays as proxy:DIR wherever a key does, it joins a
library as a user's model does, and bad input stops `tsf proxy train` with one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch", reason="the `train` extra is not installed")

import torch as th  # noqa: E402

from services.agent import add, library, networks  # noqa: E402
from services.agent.networks import ProxyPolicy, inputs  # noqa: E402
from services.agent.seats import policy_for  # noqa: E402
from services.commands.app import app  # noqa: E402
from services.commands.entry import run  # noqa: E402
from services.population.partners import make_partner  # noqa: E402
from services.proxy import train  # noqa: E402
from services.proxy.data import extract  # noqa: E402
from services.proxy.data_test import trials  # noqa: E402
from services.proxy.synthetic import record_trial  # noqa: E402
from services.sim.play import play  # noqa: E402
from shared.errors import UsageError  # noqa: E402
from shared.game import GameConfig  # noqa: E402

QUICK = ["--epochs", "3", "--patience", "2", "--hidden", "16"]


@pytest.fixture(scope="module")
def proxy(tmp_path_factory):
    """A bait proxy of three stand-in participants, trained by the command."""
    directory = tmp_path_factory.mktemp("proxy")
    paths = trials(directory / "recordings", 4, config=GameConfig(frames=600))
    out = directory / "bait-proxy"
    args = ["proxy", "train", *map(str, paths), "--role", "bait", "--out", str(out), *QUICK]
    assert run(app, args) == 0
    return out, paths


def test_the_manifest_names_data_split_metrics_and_command(proxy):
    out, paths = proxy
    record = json.loads((out / "manifest.json").read_text())
    assert [r["sha256"] for r in record["recordings"]] == [library.file_hash(p) for p in paths]
    assert record["sha256"] == library.file_hash(out / "proxy.npz")
    assert set(record["split"]["train"]) | set(record["split"]["held_out"]) == set(record["participants"])
    assert not set(record["split"]["train"]) & set(record["split"]["held_out"])
    assert record["metrics"]["held_out_loglik"] < 0 and 1 <= record["metrics"]["best_epoch"] <= 3
    assert record["command"].startswith("tsf proxy train") and len(record["excluded"]) == 4
    curve = (out / "curve.csv").read_text().splitlines()
    assert curve[0] == "epoch,train_loglik,held_out_loglik" and len(curve) == 1 + record["metrics"]["epochs"]
    assert (out / "curve.png").stat().st_size > 0


def torch_probs(directory, hidden: int, history: int, obs: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """The torch network with the exported weights, in float64: every action's probability."""
    with np.load(directory / "proxy.npz", allow_pickle=False) as data:
        layers = [(data[f"w{i}"], data[f"b{i}"]) for i in range(2)]
    model = train.network((hidden,), history).double()
    for linear, (w, b) in zip([m for m in model if isinstance(m, th.nn.Linear)], layers, strict=True):
        linear.weight.data, linear.bias.data = th.as_tensor(w).double(), th.as_tensor(b).double()
    with th.no_grad():
        rows = th.as_tensor(inputs(obs, previous, history)).repeat_interleave(12, dim=0)
        actions = th.arange(12).repeat(len(obs))
        return th.exp(train.log_likelihood(model, rows, actions)).reshape(-1, 12).numpy()


def test_numpy_probs_are_the_torch_softmax(proxy, tmp_path):
    out, paths = proxy
    policy = policy_for(f"proxy:{out}", "bait")
    assert isinstance(policy, ProxyPolicy) and policy.key == f"proxy:{out.name}"
    data = extract(paths, "bait")
    obs, previous = data.obs[:200], data.previous[:200]
    expected = torch_probs(out, 16, 0, obs, previous)
    np.testing.assert_allclose(policy.probs_batch(obs), expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(policy.probs(obs[0]), expected[0], rtol=1e-12)
    assert np.allclose(expected.sum(axis=1), 1.0)
    held = tmp_path / "held"  # a proxy that reads its last two actions
    train.train(paths, "bait", held, train.Settings((16,), 2, 1, history=2))
    remembering = policy_for(f"proxy:{held}", "bait")
    expected = torch_probs(held, 16, 2, obs, previous)
    np.testing.assert_allclose(remembering.probs_given(obs, previous), expected, rtol=1e-12, atol=1e-15)
    one = obs[:1]
    assert not np.allclose(remembering.probs_given(one, [[0, 0]]), remembering.probs_given(one, [[5, 0]]))
    remembering.reset(3)
    first = remembering.act(obs[0])
    assert remembering.played.tolist() == [first, 0]
    np.testing.assert_allclose(
        remembering.probs(obs[1]), remembering.probs_given(obs[1:2], np.array([[first, 0]]))[0]
    )
    with pytest.raises(UsageError, match="reads its own last actions"):
        add.add("HELD", held, "bait", tmp_path / "lib", games=0)


def test_a_proxy_plays_as_a_key_and_as_a_partner(proxy, capsys):
    out, _ = proxy
    key = f"proxy:{out}"
    capsys.readouterr()
    assert run(app, ["game", "--bait", key, "--shooter", "S5", "--frames", "100"]) == 0
    assert "kills" in capsys.readouterr().out
    for partner in (key, f"human({key})", f"noisy({key})"):
        result = play(make_partner(partner, "bait"), policy_for("S5", "shooter"), 1, GameConfig(frames=60))
        assert result.frames == 60
    with pytest.raises(UsageError, match="proxy of the bait seat"):
        policy_for(key, "shooter")
    with pytest.raises(UsageError, match="not a proxy directory"):
        policy_for(f"proxy:{out.parent}", "bait")


def test_a_proxy_joins_a_library_as_a_users_model_does(proxy, tmp_path, monkeypatch):
    out, _ = proxy
    mine = tmp_path / "mylib"
    args = ["library", "add", "MYPROXY", str(out), "--role", "bait", "--library", str(mine), "--games", "1"]
    assert run(app, args) == 0
    monkeypatch.setenv("TSF_LIBRARY", str(mine))
    library.forget()
    joined, direct = networks.load("MYPROXY"), policy_for(f"proxy:{out}", "bait")
    assert isinstance(joined, ProxyPolicy) and library.registry()["MYPROXY"].family == "proxy"
    obs = np.random.default_rng(0).normal(size=(20, 64)).astype(np.float32)
    np.testing.assert_array_equal(joined.probs_batch(obs), direct.probs_batch(obs))
    assert run(app, ["library", "add", "OTHER", str(out), "--role", "shooter", "--library", str(mine)]) == 2


def test_bad_input_is_one_line_and_nothing_is_written(proxy, tmp_path, capsys):
    _, paths = proxy
    shooter = trials(tmp_path / "shooter", 1, role="shooter", person="human(S5)")
    damaged = tmp_path / "damaged.tsflog"
    data = bytearray(paths[0].read_bytes())
    data[len(data) // 2 : len(data) // 2 + 64] = bytes(64)
    damaged.write_bytes(bytes(data))
    cases = {
        "one seat at a time": ([*paths, *shooter], 2),
        "damaged recording": ([*paths, damaged], 1),
        "1 participant": (paths[:1], 1),
    }
    for i, (message, (given, status)) in enumerate(cases.items()):
        out = tmp_path / f"out{i}"
        capsys.readouterr()
        assert (
            run(app, ["proxy", "train", *map(str, given), "--role", "bait", "--out", str(out), *QUICK])
            == status
        )
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0] and err[0].startswith("tsf proxy")
        assert not (out / "proxy.npz").exists()


@pytest.mark.slow  # a minute: two proxies trained, then team games with every shooter
def test_eval_partners_from_a_study_trains_one_proxy_per_participant(tmp_path, capsys):
    study = tmp_path / "study"
    config = GameConfig(frames=1200)
    for p in range(2):
        for t in range(2):
            name = f"s-p{p}-t{t}"
            record_trial(study / f"{name}.tsflog", "human(B5)", "bait", "S5", 10 * p + t, f"p{p}", config)
    record_trial(study / "s-q-t0.tsflog", "human(S5)", "shooter", "B5", 99, "q", config)  # the other seat
    out = tmp_path / "eval"
    args = ["eval", "--partners-from", str(study), "--no-identify", "--seeds", "1", "--window", "150"]
    args += ["--strategy", "cem", "--workers", "1", "--out", str(out)]
    assert run(app, args) == 0
    printed = capsys.readouterr().out
    assert "participant q played the shooter" in printed
    manifests = {p: out / "proxies" / p / "manifest.json" for p in ("p0", "p1")}
    assert all(json.loads(m.read_text())["split"]["by"] == "recording" for m in manifests.values())
    per_partner = (out / "per_partner.csv").read_text()
    for p in ("p0", "p1"):
        assert f"proxy:{out / 'proxies' / p},proxy," in per_partner
    assert "Team performance (2 partners" in (out / "summary.md").read_text()
    made = {p: m.stat().st_mtime_ns for p, m in manifests.items()}
    assert run(app, args) == 0  # the proxies loaded, not retrained (the games from the journal)
    assert {p: m.stat().st_mtime_ns for p, m in manifests.items()} == made
    assert run(app, [*args, "--partner", "B5"]) == 2
