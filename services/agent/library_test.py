"""The shipped library: every policy loads by key, follows the protocol and samples what it says."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from services.agent import library, networks, seats
from services.sim.engine import Game
from services.sim.observation import observe
from services.table.table import (
    Table,  # imported here, not under the test's TSF_LIBRARY: its default table is read once
)
from shared.errors import UsageError
from shared.game import N_ACTIONS, ROLES, GameConfig, Policy

KEYS = library.keys()


def observations(role: str, view: str, n: int = 40) -> list[np.ndarray]:
    """Observations from a few frames of random play (ships moving, shells flying)."""
    game, rng, out = Game(GameConfig(), seed=3), np.random.default_rng(0), []
    for _ in range(n * 10):
        game.step(int(rng.integers(N_ACTIONS)), int(rng.integers(N_ACTIONS)))
        if game.frame % 10 == 0:
            out.append(observe(game, role, view))
    return out


def test_registry_names_the_papers_library():
    assert library.keys("bait") == [f"B{i}" for i in range(1, 10)]
    assert library.keys("shooter") == [f"S{i}" for i in range(1, 8)]
    recipes = library.registry()
    assert {recipes[k].algorithm for k in ("S4", "S5", "S6", "S7")} == {None}
    assert {recipes[k].algorithm for k in ("B1", "B2", "B3")} == {"A2C"}
    assert {recipes[k].algorithm for k in ("S1", "S2", "S3")} == {"DQN"}


@pytest.mark.parametrize("key", KEYS)
def test_policy_conforms_and_never_gives_zero(key):
    policy = networks.load(key)
    recipe = library.registry()[key]
    assert isinstance(policy, Policy)
    assert (policy.key, policy.role) == (key, recipe.role) and policy.view in ("world", "role")
    policy.reset(7)
    for obs in observations(policy.role, policy.view):
        p = policy.probs(obs)
        assert p.shape == (N_ACTIONS,)
        assert p.sum() == pytest.approx(1.0, abs=1e-9)
        assert p.min() > 0.0
        assert 0 <= policy.act(obs) < N_ACTIONS


@pytest.mark.parametrize("key", ["B1", "B5", "S1", "S4"])
def test_act_samples_the_distribution_probs_reports(key):
    policy = networks.load(key)
    obs = observations(policy.role, policy.view)[5]
    p = policy.probs(obs)
    policy.reset(1)
    n = 4000
    counts = np.bincount([policy.act(obs) for _ in range(n)], minlength=N_ACTIONS)
    # every action's frequency within 5 standard errors of its probability
    assert np.all(np.abs(counts / n - p) <= 5 * np.sqrt(p * (1 - p) / n) + 1e-3)


def test_same_seed_same_actions():
    a, b = networks.load("B5"), networks.load("B5")
    obs = observations("bait", "role")
    a.reset(11)
    b.reset(11)
    assert [a.act(o) for o in obs] == [b.act(o) for o in obs]


def test_policy_for_resolves_library_and_scripted_keys():
    assert seats.policy_for("S5", "shooter").key == "S5"
    assert seats.policy_for("circle", "bait").key == "circle"


BAITS = "B1, B2, B3, B4, B5, B6, B7, B8, B9, circle, orbit, idle, random"


@pytest.mark.parametrize(
    ("key", "role", "option", "line"),
    [
        ("B99", "bait", "--bait", f"--bait B99: no policy of the bait seat; valid: {BAITS}"),
        ("S5", "bait", "--policy", f"--policy S5: plays the shooter seat, not the bait; valid: {BAITS}"),
        ("mirror", "bait", "--bait", f"--bait mirror: plays the shooter seat, not the bait; valid: {BAITS}"),
        (
            "circle",
            "shooter",
            "--shooter",
            "--shooter circle: plays the bait seat, not the shooter; valid: S1,",
        ),
        ("circle", "pilot", "--policy", "--role pilot: not a seat; valid: bait, shooter"),
    ],
)
def test_a_key_that_cannot_play_the_seat_is_named_with_every_key_that_can(
    key: str, role: str, option: str, line: str
) -> None:
    with pytest.raises(UsageError) as refused:
        seats.policy_for(key, role, option)
    assert str(refused.value).startswith(line)
    assert seats.seat_keys("shooter")[-3:] == ["mirror", "idle", "random"]


def test_a_shooter_recipe_can_thrust_by_the_baits_speed_cap():
    """The study's RL shooters differ in max speed: thrust_rule = "speed-cap" gives a shooter's
    thrust head the baits' rule (thrust while under the cap), its fire head unchanged."""
    config, mirror = GameConfig(), library.registry()["S1"]
    capped = replace(mirror, thrust_rule="speed-cap")
    rows = np.array(observations("shooter", "world", 80))
    under = np.array([networks.speed(o) < capped.speed_cap for o in rows])
    assert under.any() and not under.all()
    batch = networks.rule_heads_batch(capped, rows, config)
    assert np.array_equal(batch["thrust"], under.astype(np.int64))
    assert [networks.rule_heads(capped, o, config) for o in rows] == [
        {"thrust": int(t), "fire": int(f)} for t, f in zip(batch["thrust"], batch["fire"], strict=True)
    ]
    mirrored = networks.rule_heads_batch(mirror, rows, config)
    assert np.array_equal(batch["fire"], mirrored["fire"])
    assert not np.array_equal(batch["thrust"], mirrored["thrust"])  # the role's own rule differs


def test_an_unknown_thrust_rule_is_named(tmp_path):
    root = copy_library(tmp_path)
    registry = root / "registry.toml"
    registry.write_text(
        registry.read_text().replace("speed_cap = 3.0", 'speed_cap = 3.0\nthrust_rule = "cap"', 1)
    )
    with pytest.raises(ValueError, match="thrust_rule = 'cap': one of mirror, speed-cap, or none"):
        library.registry(root)


def test_every_scripted_rule_is_a_family_a_library_entry_can_name(tmp_path, monkeypatch):
    """A grown library's members are rules with their settings: the bait's orbit too."""
    root = empty_library(tmp_path / "mine")
    library.write_registry(
        root,
        {
            "XB1": {"role": "bait", "family": "orbit", "description": "an orbit", "rule": {"radius": 190.0}},
            "XS1": {
                "role": "shooter",
                "family": "mirror",
                "description": "a mirror",
                "rule": {"radius": 200.0},
            },
        },
    )
    monkeypatch.setenv("TSF_LIBRARY", str(root))
    orbit = networks.load("XB1")
    assert orbit.radius == 190.0 and np.isclose(orbit.probs(np.zeros(64, np.float32)).sum(), 1.0)
    assert networks.load("XS1").radius == 200.0


def copy_library(tmp_path: Path) -> Path:
    return library.copy(tmp_path / "library")


def empty_library(path: Path) -> Path:
    """A library of one's own with no policies yet (nor a table or thresholds), for TSF_LIBRARY."""
    path.mkdir()
    (path / "registry.toml").write_text("")
    (path / "manifest.json").write_text("{}")
    return path


def test_a_copy_is_the_shipped_library_but_its_table_and_is_never_overwritten(tmp_path):
    root = copy_library(tmp_path)
    assert library.manifest_hash(root) == library.manifest_hash()
    keys = library.keys()
    assert [networks.load(k, root=root).key for k in keys] == keys
    assert not (root / "table.json").exists()  # a retrained policy would make it stale
    (root / "manifest.json").write_text("{}")
    library.copy(root)  # an existing library is left as it is: `tsf train` adds to it
    assert library.manifest(root) == {}


def test_tampered_weights_are_refused(tmp_path):
    root = copy_library(tmp_path)
    path = root / library.manifest(root)["B2"]["file"]
    data = bytearray(path.read_bytes())
    data[-100] ^= 1
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="does not match its manifest hash"):
        networks.load("B2", root=root)


def test_untrained_policy_says_how_to_train_it(tmp_path):
    root = copy_library(tmp_path)
    (root / "manifest.json").write_text(json.dumps({}))
    with pytest.raises(FileNotFoundError, match=f"run `tsf train B3 --out {root}`"):
        networks.load("B3", root=root)


def test_weights_never_unpickle(tmp_path):
    path = tmp_path / "evil.npz"
    np.savez(path, w0=np.array([object()], dtype=object), meta=np.frombuffer(b"{}", np.uint8))
    with pytest.raises(ValueError, match="allow_pickle"):
        networks.Network.load(path)


def test_manifest_records_every_learned_policy():
    manifest = library.manifest()
    for key, recipe in library.registry().items():
        if recipe.algorithm is None:
            continue
        entry = manifest[key]
        assert entry["sha256"] == library.file_hash(library.LIBRARY / entry["file"])
        assert entry["algorithm"] == recipe.algorithm and entry["steps"] > 0
        assert entry["command"].startswith(f"tsf train {key}")
        assert entry["score"]["games"] >= 10


@pytest.mark.parametrize("role", ROLES)
def test_manifest_hash_changes_with_the_manifest(tmp_path, role):
    root = copy_library(tmp_path)
    before = library.manifest_hash(root)
    manifest = library.manifest(root)
    key = next(k for k in manifest if library.registry()[k].role == role)
    manifest[key]["seed"] += 1
    (root / "manifest.json").write_text(json.dumps(manifest))
    assert library.manifest_hash(root) != before


def test_the_play_hash_covers_what_an_adaptive_agent_reads_in_a_library_in_use(tmp_path, monkeypatch):
    """A study's hosts must agree on it: another groups file (or table) in use changes it, where the
    manifest's hash does not."""
    root = copy_library(tmp_path)
    monkeypatch.setenv("TSF_LIBRARY", str(root))
    before, manifest = library.play_hash(), library.manifest_hash()
    (root / "groups.json").write_text(json.dumps({"version": 1, "seats": {}}))
    assert library.play_hash() != before and library.manifest_hash() == manifest
    monkeypatch.delenv("TSF_LIBRARY")
    assert library.play_hash() != before  # the libraries in use are part of it


def test_the_grown_library_is_named_and_plays_with_its_own_table(tmp_path, monkeypatch):
    """TSF_LIBRARY=grown is the library shipped beside the study's (a directory of that name here
    would be taken instead); its members play and its table is bound to it."""
    monkeypatch.setenv("TSF_LIBRARY", "grown")
    monkeypatch.chdir(tmp_path)
    assert library.roots() == [library.LIBRARY, library.NAMED["grown"]]
    grown = [k for k in library.registry() if k.startswith(("GB", "GS"))]
    assert grown and all(library.registry()[k].root == library.NAMED["grown"] for k in grown)
    table = Table.load(library.table_path())  # checked against the libraries in use
    assert set(table.baits) | set(table.shooters) == set(grown)
    for key in grown:
        policy = networks.load(key)
        assert policy.probs(np.zeros(64, np.float32)).sum() == pytest.approx(1.0)
    (tmp_path / "grown").mkdir()
    assert library.roots()[-1] == Path("grown")


def test_the_writer_records_what_a_library_lacks_and_copies_members_with_their_hashes(tmp_path):
    mine, other = tmp_path / "mine", tmp_path / "other"
    rule = {"role": "bait", "family": "circle", "description": 'a "circle"', "rule": {"radius": 150.0}}
    learned = {"role": "shooter", "family": "events", "description": "x", "algorithm": "PPO"}
    learned |= {"learned": ["turn"], "features": "shooter", "weights": {"kill": 1.0}, "steps": 2048}
    library.record(mine, {"MB1": rule})
    library.record(mine, {"MB1": rule | {"description": "changed"}, "MS1": learned})  # MB1 is kept
    recorded = library.registry(mine)
    assert list(recorded) == ["MB1", "MS1"] and recorded["MB1"].description == 'a "circle"'
    assert recorded["MS1"].weights == {"kill": 1.0} and recorded["MS1"].learned == ("turn",)
    library.write_registry(other, {"MS1": learned})
    (other / "weights").mkdir()
    (other / "weights" / "MS1.npz").write_bytes(b"weights")
    library.write_manifest(other, {"MS1": {"file": "weights/MS1.npz", "sha256": "stale", "steps": 2048}})
    library.adopt_members(other, mine, ["MS1"])
    entry = library.manifest(mine)["MS1"]
    assert (mine / entry["file"]).read_bytes() == b"weights" and entry["steps"] == 2048
    assert entry["sha256"] == library.file_hash(mine / "weights" / "MS1.npz")  # the copy's own hash
    assert list(library.registry(other)) == ["MS1"]
