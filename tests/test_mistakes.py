"""A user's mistakes across the commands, run in-process as `tsf` runs them (services/commands/entry.py): each
ends in one line that names the option, the value and what is accepted, exit status 2 (usage) or 1
(failure), and never a traceback."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from importlib import resources
from importlib.util import find_spec
from pathlib import Path

import pytest
import typer

from services.agent import library
from services.agent.library_test import empty_library
from services.commands.app import app
from services.commands.entry import run
from services.recorder.recording_test import M, record_match
from shared.errors import UsageError, install_line

BAITS = "B1, B2, B3, B4, B5, B6, B7, B8, B9, circle, orbit, idle, random"
SHOOTERS = "S1, S2, S3, S4, S5, S6, S7, mirror, idle, random"
STRATEGIES = (
    "cem, cem-dwell, cem-ood, bayes, bayes-dwell-ood, bayes-dwell-ood-guard, bayes-dwell-ood-guard-memory, "
    "bayes-dwell-ood-guard-skill"
)
SEED_RANGE = "0 to 4294967295"

# (command line, exit status, what the one line says); {tmp} is a directory that holds the finished
# recording {done} (match id M), its torn copy {torn}, one with a wrong state hash {tampered}, and
# {garbage}, a file that is no recording.


def refused(option: str, value: str, choices: str, envvar: str = "") -> str:
    """Click's line for a value outside an option's choices."""
    env = f" (env var: '{envvar}')" if envvar else ""
    return f"Invalid value for '{option}'{env}: Value error, '{value}' is not one of {choices}"


SEATS = "'bait', 'shooter'"
MODES = "'peer', 'client', 'router'"
SIM_MODES = "'realtime', 'lockstep'"
STRATEGY_CHOICES = "'cem', 'cem-dwell', 'cem-ood', 'bayes', 'bayes-dwell-ood'"
SERVICES = "'sim', 'agent', 'recorder'"

MISTAKES = [
    ("nosuch", 2, "tsf: No such command 'nosuch'."),
    ("game --nosuch", 2, "tsf game: No such option: --nosuch"),
    ("game --games 0", 2, "tsf game: Invalid value for '--games': 0 is outside the range 1 to 10000"),
    ("game --frames 0", 2, "Invalid value for '--frames': 0 is outside the range 1 to 108000"),
    ("game --seed x", 2, "tsf game: Invalid value for '--seed': x is not a number"),
    ("game --bait B99", 2, f"tsf game: --bait B99: no policy of the bait seat; valid: {BAITS}"),
    ("game --bait S4", 2, f"tsf game: --bait S4: plays the shooter seat, not the bait; valid: {BAITS}"),
    (
        "game --shooter circle",
        2,
        f"--shooter circle: plays the bait seat, not the shooter; valid: {SHOOTERS}",
    ),
    ("game --shooter B1", 2, f"--shooter B1: plays the bait seat, not the shooter; valid: {SHOOTERS}"),
    ("calibrate --games 1", 2, "Invalid value for '--games': 1 is outside the range 2 to 10000"),
    ("train NOPE", 2, "tsf train: KEYS NOPE: not a learned policy of the library; valid: B"),
    (
        "library grow --population {garbage} --out {tmp}/grown",
        2,
        "tsf library: --population {garbage}: cannot be read as TOML",
    ),
    (
        "library grow --population {tmp}/empty.toml --out {tmp}/grown",
        2,
        "tsf library: --population {tmp}/empty.toml: split: missing (a required setting)",
    ),
    (
        "library grow --out {tmp}/grown-other",
        2,
        "tsf library: --out {tmp}/grown-other: was grown from another population spec (0123456789abcdef)",
    ),
    (
        "library condition {tmp} --seat bait",
        2,
        "tsf library: OUT {tmp}: is no finished `tsf library grow` run (no library/groups.json)",
    ),
    ("library condition {tmp} --seat ours", 2, "Invalid value for '--seat'"),
    (
        "library search --seat shooter --run {tmp} --out {tmp}/searched",
        2,
        "tsf library: --run {tmp}: is no grown run's library (no run-population.json, run-groups.json",
    ),
    ("library search --seat shooter --trials 0", 2, "'--trials': 0 is outside the range 1 to 10000"),
    (
        "library search --seat shooter --family orbit",
        2,
        "tsf library: --family orbit: is no searchable rule of the shooter seat; valid: mirror",
    ),
    ("train --steps 0", 2, "Invalid value for '--steps'"),
    ("train", 2, "tsf train: KEYS (none): give library keys or --all, not both"),
    ("train B1 --all", 2, "tsf train: KEYS B1: give library keys or --all, not both"),
    ("train B1 --jobs 0", 2, "'--jobs': 0 is outside the range 1 to 64"),
    ("diversity --games 0", 2, "Invalid value for '--games'"),
    (
        "diversity --bait-partner B1",
        2,
        f"--bait-partner B1: plays the bait seat, not the shooter; valid: {SHOOTERS}",
    ),
    (
        "diversity --shooter-partner ZZ",
        2,
        f"--shooter-partner ZZ: no policy of the bait seat; valid: {BAITS}",
    ),
    ("sweep --bait B99", 2, "tsf sweep: Invalid value: not baits of the library: ['B99']"),
    ("sweep --shooter B1", 2, "not shooters of the library: ['B1']"),
    ("sweep --games 0", 2, "Invalid value for '--games'"),
    ("sweep --chunk 0", 2, "Invalid value for '--chunk'"),
    (
        "sweep --mode banana",
        2,
        "tsf sweep: " + refused("--mode", "banana", MODES, "TSF_MODE"),
    ),
    (
        "worker --mode banana",
        2,
        "tsf worker: " + refused("--mode", "banana", MODES, "TSF_MODE"),
    ),
    ("worker --connect nowhere", 2, "--connect nowhere: not a zenoh endpoint such as tcp/127.0.0.1:7447"),
    ("worker --slots 0", 2, "--slots"),
    (
        "sweep --workers 0 --out {tmp}/t.json",
        2,
        "tsf sweep: --workers 0: no worker could reach this coordinator",
    ),
    ("eval --workers 0 --out {tmp}/e", 2, "tsf eval: --workers 0: no worker could reach this coordinator"),
    ("eval --job-games 1001", 2, "--job-games"),
    (
        "eval --games {garbage} --out {tmp}/e",
        2,
        "tsf eval: --games {garbage}: not an evaluation's team.csv; valid: partner, agent, seed, "
        "kills_per_minute, switches, guarded",
    ),
    ("eval --games {tmp}/none.csv --out {tmp}/e", 2, "tsf eval: --games {tmp}/none.csv: cannot be read"),
    (
        "table {tmp}/none.json",
        2,
        "tsf table: Invalid value for 'path': file '{tmp}/none.json' does not exist.",
    ),
    ("sim --match a/b", 2, "tsf sim: --match a/b: invalid match id: use 1-64 letters, digits, '-' or '_'"),
    ("sim --match x --pool p", 2, "tsf sim: --pool p: give --pool or --match, not both"),
    ("sim", 2, "tsf sim: --match (none): give --match (one match) or --pool (a pool's matches)"),
    ("sim --pool a/b", 2, "tsf sim: --pool a/b: invalid pool name: use 1-64 letters, digits, '-' or '_'"),
    (
        "sim --match x --sim-mode fast",
        2,
        "tsf sim: " + refused("--sim-mode", "fast", SIM_MODES),
    ),
    ("sim --match x --frames 0", 2, "Invalid value for '--frames'"),
    ("sim --match x --listen garbage", 2, "tsf sim: --listen garbage: not a zenoh endpoint"),
    (
        "sim --match x --mode hub",
        2,
        "tsf sim: " + refused("--mode", "hub", MODES, "TSF_MODE"),
    ),
    (
        "agent --match x --role pilot --policy circle",
        2,
        "tsf agent: " + refused("--role", "pilot", SEATS),
    ),
    (
        "agent --match x --role bait --policy S4",
        2,
        f"--policy S4: plays the shooter seat, not the bait; valid: {BAITS}",
    ),
    (
        "agent --match x --role shooter --policy zz",
        2,
        f"--policy zz: no policy of the shooter seat; valid: {SHOOTERS}",
    ),
    ("agent --match x --policy circle", 2, "tsf agent: --role (none): needed with --match"),
    ("agent --match x --role bait", 2, "tsf agent: --policy (none): needed with --match"),
    ("agent --match x --pool p", 2, "tsf agent: --pool p: give --pool or --match, not both"),
    ("agent --role bait", 2, "tsf agent: --match (none): give --match (one match) or --pool"),
    ("adapter --pool 'a b'", 2, "tsf adapter: --pool a b: invalid pool name"),
    ("agent --match 'bad id' --role bait --policy circle", 2, "--match bad id: invalid match id"),
    ("recorder --match x/y", 2, "tsf recorder: --match x/y: invalid match id"),
    ("recorder", 2, "tsf recorder: --match (none): give --match (one match) or --pool (a pool's matches)"),
    ("recorder --match x --pool p", 2, "tsf recorder: --pool p: give --pool or --match, not both"),
    ("recorder --pool p/q", 2, "tsf recorder: --pool p/q: invalid pool name"),
    ("recorder --match " + M + " --out {tmp}", 2, f"--match {M}: {{done}} holds a finished match of this id"),
    (
        "adapter --match x --role pilot",
        2,
        "tsf adapter: " + refused("--role", "pilot", SEATS),
    ),
    (
        "adapter --match x --strategy oracle",
        2,
        "tsf adapter: " + refused("--strategy", "oracle", STRATEGY_CHOICES),
    ),
    ("adapter --match x --initial best", 2, "--initial best: unknown; valid: best-average, random"),
    ("adapter --match x --window 0", 2, "tsf adapter: --window 0: outside the range 1 to 108000"),
    ("adapter --match x --hazard 1.5", 2, "tsf adapter: --hazard 1.5: a probability in [0, 1)"),
    ("adapter --match x --noise -1", 2, "tsf adapter: --noise -1.0: a probability in [0, 1)"),
    ("router --credentials {tmp}/none.txt", 2, "tsf router: --credentials {tmp}/none.txt: no such file"),
    (
        "alive --match x --service banana",
        2,
        refused("--service", "banana", SERVICES),
    ),
    (
        "alive --match x --service agent --role pilot",
        2,
        "tsf alive: " + refused("--role", "pilot", SEATS),
    ),
    ("match --bait B99", 2, f"tsf match: --bait B99: no policy of the bait seat; valid: {BAITS}"),
    ("match --bait S4", 2, f"tsf match: --bait S4: plays the shooter seat, not the bait; valid: {BAITS}"),
    (
        "match --shooter B1",
        2,
        f"tsf match: --shooter B1: plays the bait seat, not the shooter; valid: {SHOOTERS}",
    ),
    ("match --shooter circle", 2, "tsf match: --shooter circle: plays the bait seat, not the shooter"),
    (
        "match --adaptive pilot",
        2,
        "tsf match: " + refused("--adaptive", "pilot", SEATS),
    ),
    (
        "match --adaptive shooter --strategy oracle",
        2,
        refused("--strategy", "oracle", STRATEGY_CHOICES),
    ),
    (
        "match --adaptive bait --shooter zz",
        2,
        "tsf match: --shooter zz: no policy of the shooter seat",
    ),
    ("match --duration 0", 2, "Invalid value for '--duration'"),
    ("match --window 0", 2, "tsf match: --window 0: outside the range 1 to 108000"),
    ("match --seed abc", 2, "Invalid value for '--seed'"),
    ("match --match a/b", 2, "tsf match: --match a/b: invalid match id"),
    (
        "match --match " + M + " --out {tmp}",
        2,
        f"--match {M}: {{done}} exists; choose another id, or --overwrite",
    ),
    (
        "replay {tmp}/none.tsflog",
        2,
        "tsf replay: Invalid value for 'recording': file '{tmp}/none.tsflog' does not",
    ),
    ("replay {tmp}", 2, "tsf replay: Invalid value for 'recording': file '{tmp}' is a directory."),
    ("replay", 2, "tsf replay: Missing argument 'recording'."),
    ("replay {garbage}", 1, "tsf replay: {garbage} is not a TSF recording (bad magic)"),
    ("replay {torn}", 1, "tsf replay: {torn}: incomplete: torn tail at bytes"),
    ("replay {tampered}", 1, "tsf replay: {tampered}: 1 states differ, first at frame 17"),
    (
        "replay {done} --video {tmp}/m.avi",
        2,
        "tsf replay: --video {tmp}/m.avi: not a video file name; valid: *.gif",
    ),
    ("replay {done} --speed 0", 2, "Invalid value for '--speed'"),
    ("replay {done} --scale 0", 2, "Invalid value for '--scale'"),
    ("human --match x --token bait", 2, "tsf human: Invalid value: give each seat as ROLE=TOKEN"),
    ("human --match x --token pilot=t", 2, "tsf human: --token pilot: unknown roles; valid: bait, shooter"),
    ("human --match x --port 70000", 2, "Invalid value for '--port'"),
    (
        "play --role pilot",
        2,
        "tsf play: " + refused("--role", "pilot", SEATS),
    ),
    ("play --partner B99", 2, f"tsf play: --partner B99: no policy of the shooter seat; valid: {SHOOTERS}"),
    (
        "play --role shooter --partner S4",
        2,
        f"tsf play: --partner S4: plays the shooter seat, not the bait; valid: {BAITS}",
    ),
    (
        "play --strategy oracle",
        2,
        "tsf play: " + refused("--strategy", "oracle", STRATEGY_CHOICES),
    ),
    ("play --window 0", 2, "tsf play: --window 0: outside the range 1 to 108000"),
    ("play --match a/b --partner S4", 2, "tsf play: --match a/b: invalid match id"),
    (
        "eval --role pilot",
        2,
        "tsf eval: " + refused("--role", "pilot", SEATS),
    ),
    ("eval --window x", 2, "Invalid value for '--window'"),
    (
        "eval --partner human(B5,skill=expert) --out {tmp}/e",
        2,
        "tsf eval: --partner human(B5,skill=expert): skill=expert is not one of novice, typical, practised",
    ),
    ("humans fit {done} --role bait --out {tmp}/h", 2, "{done}: no person played the bait seat"),
    ("humans fit {garbage} --role bait --out {tmp}/h", 1, "unreadable recording"),
    ("eval --strategy nope", 2, "Invalid value for '--strategy'"),
    ("eval --strategy-window 0", 2, "Invalid value for '--strategy-window'"),
    ("calibrate-adapter --workers -1", 2, "Invalid value for '--workers'"),
    ("report", 2, "tsf report: Missing argument 'recordings'."),
    (
        "report {done} --partner-role pilot",
        2,
        refused("--partner-role", "pilot", SEATS),
    ),
    ("report {done} --reference-games 0", 2, "Invalid value for '--reference-games'"),
    ("report {garbage} {torn} --out {tmp}/report", 1, "none of the 2 recordings is usable; {tmp}/report"),
    (
        "study {tmp}/none.toml",
        2,
        "tsf study: Invalid value for 'config': file '{tmp}/none.toml' does not exist.",
    ),
    ("study {garbage}", 2, "tsf study: CONFIG {garbage}: not a study: Expected '=' after a key"),
    ("study {tmp}/empty.toml", 2, "tsf study: CONFIG {tmp}/empty.toml: not a study: "),
    # Options that another makes do nothing, or that together ask for nothing, are refused.
    (
        "eval --games {garbage} --partner B1",
        2,
        "tsf eval: --partner with --games {garbage}: does nothing there (its games are analysed as they "
        "were played): leave one out",
    ),
    ("eval --games {garbage} --sessions", 2, "tsf eval: --sessions with --games {garbage}: does nothing"),
    ("eval --games {garbage} --seeds 3", 2, "tsf eval: --seeds with --games {garbage}: does nothing"),
    (
        "eval --no-identify --no-performance",
        2,
        "tsf eval: --no-identify with --no-performance: measures nothing",
    ),
    # A population is chosen once: partners beside a named one, or strategies beside a test split
    # (which measures the shipped agents), are refused before anything runs.
    (
        "eval --held-out --partner B5 --out {tmp}/e",
        2,
        "tsf eval: --partner B5: beside --held-out: give partners or a population, not both",
    ),
    (
        "eval --population held-out --partners-from {tmp} --out {tmp}/e",
        2,
        "tsf eval: --partners-from {tmp}: beside --population held-out: give partners or a population",
    ),
    (
        "eval --held-out --strategy cem --out {tmp}/e",
        2,
        "tsf eval: --strategy cem: beside --held-out: a test split measures the shipped agents at "
        "--strategy-window, not the study's variants; compare those on another population; valid: default",
    ),
    (
        "eval --population held-out --variants --out {tmp}/e",
        2,
        "tsf eval: --variants given: beside --population held-out: a test split measures the shipped agents",
    ),
    ("eval --held-out --population default", 2, "tsf eval: --held-out with --population default: give one"),
    (
        "eval --population nope --out {tmp}/e",
        2,
        "tsf eval: --population nope: not a population; valid: default, held-out, a grown library",
    ),
    ("eval --games {garbage} --population held-out", 2, "tsf eval: --population with --games {garbage}"),
    (
        "match --adaptive shooter --shooter S4",
        2,
        "tsf match: --shooter with --adaptive shooter: does nothing there (the adaptive agent plays that "
        "seat): leave one out",
    ),
    ("match --adaptive bait --bait B5", 2, "tsf match: --bait with --adaptive bait: does nothing there"),
    (
        "study {tmp}/typo.toml",
        2,
        "tsf study: CONFIG {tmp}/typo.toml: not a study: trial_secnds: no such setting; valid: name, "
        "variants, trials, trial_seconds,",
    ),
    (
        "study {tmp}/text.toml",
        2,
        'tsf study: CONFIG {tmp}/text.toml: not a study: crowd.bonus.max = "2": a number expected',
    ),
    (
        "study {tmp}/s55.toml --check",
        2,
        "tsf study: CONFIG {tmp}/s55.toml: not a study: variant B8-S5 (the shooter seat): shooter = S55: "
        f"no policy of the shooter seat; valid: {SHOOTERS}",
    ),
    ("study {tmp}/long.toml --max-matches 0", 2, "tsf study: --max-matches 0: no match could run"),
    ("study {tmp}/long.toml --listen nowhere", 2, "tsf study: --listen nowhere: not a zenoh endpoint"),
    (
        "study {tmp}/long.toml --link-secret {tmp}/empty.toml",
        2,
        "tsf study: --link-secret {tmp}/empty.toml: the secret needs at least 16 characters, it has 0",
    ),
    ("study {tmp}/long.toml --link-secret {tmp}", 2, "TSF_LINK_SECRET_FILE'): file '{tmp}' is a directory."),
    (
        "study {tmp}/long.toml --dashboard-token {tmp}/empty.toml",
        2,
        "tsf study: --dashboard-token {tmp}/empty.toml: 0 characters: give 16 to 64",
    ),
    (
        "study {tmp}/long.toml --dashboard-token {garbage} --dashboard-port 8000",
        2,
        "tsf study: --dashboard-port 8000: the participants' port: give another",
    ),
    (
        "study {tmp}/long.toml --trusted-proxy proxy.example",
        2,
        "tsf study: --trusted-proxy proxy.example: an IP address, e.g. 127.0.0.1 or ::1",
    ),
    (
        "study {tmp}/static.toml --check --max-matches 0",
        2,
        "tsf study: --max-matches 0: no match could run: give match hosts with --listen or --connect, or 1",
    ),
    (
        "study {tmp}/static.toml --check --trusted-proxy proxy.example",
        2,
        "tsf study: --trusted-proxy proxy.example: an IP address, e.g. 127.0.0.1 or ::1",
    ),
    (
        "study {tmp}/static.toml --check --key {garbage}",
        2,
        "tsf study: --cert/--key {garbage}: --cert is missing: give both, or neither",
    ),
    (
        "study {tmp}/static.toml --check --cert {garbage}",
        2,
        "tsf study: --cert/--key {garbage}: --key is missing: give both, or neither",
    ),
    (
        "study {tmp}/static.toml --check --cert {garbage} --key {garbage}",
        2,
        "tsf study: --cert/--key {garbage} {garbage}: not a PEM certificate chain and its key",
    ),
    (
        "study {tmp}/spaced.toml --check",
        2,
        "tsf study: CONFIG {tmp}/spaced.toml: not a study: variants[1]: variant name 'B1-S1 ': "
        "1-64 printable characters, no blank at either end",
    ),
    (
        "study {tmp}/blank-code.toml --check",
        2,
        "tsf study: CONFIG {tmp}/blank-code.toml: not a study: crowd.completion_code '   ': the platform's "
        "code, without blanks at either end",
    ),
    ("study {tmp}/long.toml --arrivals 0", 2, "'--arrivals': 0 is outside the range 0.01 to 1000.0"),
    ("match-host", 2, "tsf match-host: --connect (none): a match host needs the router's endpoint"),
    (
        "match-host --slots 0 --connect tcp/127.0.0.1:1",
        2,
        "'--slots': 0 is outside the range 1 to 1024",
    ),
    (
        "match-host --connect tcp/127.0.0.1:1",
        2,
        "tsf match-host: --host-secret (none): the study server and its match hosts need a shared secret",
    ),
    (
        "study {tmp}/long.toml --connect tcp/127.0.0.1:1",
        2,
        "tsf study: --host-secret (none): the study server and its match hosts need a shared secret",
    ),
    (
        "match-host --connect tcp/127.0.0.1:1 --host-secret {tmp}/empty.toml",
        2,
        "tsf match-host: --host-secret {tmp}/empty.toml: the secret needs at least 16 characters",
    ),
    (
        "match-host --mode client --connect tcp/127.0.0.1:1 --wait-router 0.2 --host-secret {garbage}",
        1,
        "tsf match-host: cannot reach the router at tcp/127.0.0.1:1: Unable to connect",
    ),
    # Values outside their limits (shared/game.py, shared/messages.py, services/commands/options.py,
    # AdapterConfig): refused before anything starts, naming the accepted range.
    ("game --seed -1", 2, f"tsf game: Invalid value for '--seed': -1 is outside the range {SEED_RANGE}"),
    ("game --frames 1000000000", 2, "'--frames': 1000000000 is outside the range 1 to 108000"),
    ("game --games 1e9", 2, "tsf game: Invalid value for '--games': 1e9 is outside the range 1 to 10000"),
    ("game --games 2.5", 2, "tsf game: Invalid value for '--games': 2.5 is not a whole number"),
    (
        "game --seed 4294967295 --games 2",
        2,
        f"tsf game: --seed 4294967295: the last game's seed 4294967296 is outside the range {SEED_RANGE}",
    ),
    ("calibrate --games 100000", 2, "'--games': 100000 is outside the range 2 to 10000"),
    (
        "match --duration 1e9",
        2,
        "tsf match: Invalid value for '--duration': 1e9 is outside the range 0.1 to 3600.0",
    ),
    ("match --duration nan", 2, "'--duration': nan is outside the range 0.1 to 3600.0"),
    ("match --seed -1", 2, f"tsf match: Invalid value for '--seed': -1 is outside the range {SEED_RANGE}"),
    ("match --window 1000000", 2, "tsf match: --window 1000000: outside the range 1 to 108000"),
    ("match --adaptive bait --warmup -1", 2, "tsf match: --warmup -1: outside the range 0 to 108000"),
    ("play --duration inf", 2, "tsf play: Invalid value for '--duration': inf is outside the range"),
    ("play --wait -5", 2, "tsf play: Invalid value for '--wait': -5 is outside the range 0.0 to 86400.0"),
    ("play --seed -2", 2, "tsf play: Invalid value for '--seed': -2 is outside the range"),
    ("sim --match x --frames 1000000000", 2, "'--frames': 1000000000 is outside the range 1 to 108000"),
    (
        "sim --match x --seed -1",
        2,
        f"tsf sim: Invalid value for '--seed': -1 is outside the range {SEED_RANGE}",
    ),
    ("sim --match x --wait-players -1", 2, "'--wait-players': -1 is outside the range 0.0 to 86400.0"),
    ("sim --match x --wait-recorder 1e9", 2, "'--wait-recorder': 1e9 is outside the range 0.0 to 86400.0"),
    ("sim --match x --wait-adapter nan", 2, "'--wait-adapter': nan is outside the range"),
    ("agent --match x --role bait --policy circle --seed -1", 2, "tsf agent: Invalid value for '--seed': -1"),
    ("adapter --match x --seed -1", 2, f"tsf adapter: --seed -1: outside the range {SEED_RANGE}"),
    (
        "adapter --match x --dwell 999999999",
        2,
        "tsf adapter: --dwell 999999999: outside the range 0 to 108000",
    ),
    ("train --seed -1", 2, f"tsf train: Invalid value for '--seed': -1 is outside the range {SEED_RANGE}"),
    (
        "train --steps 1e12",
        2,
        "tsf train: Invalid value for '--steps': 1e12 is outside the range 1 to 1000000000",
    ),
    ("train --score-games -1", 2, "'--score-games': -1 is outside the range 0 to 10000"),
    (
        "sweep --games 1000000",
        2,
        "tsf sweep: Invalid value for '--games': 1000000 is outside the range 1 to 10000",
    ),
    ("sweep --chunk 5000", 2, "tsf sweep: Invalid value for '--chunk': 5000 is outside the range 1 to 1000"),
    ("sweep --workers 100000", 2, "'--workers': 100000 is outside the range 0 to 256"),
    (
        "diversity --games -3",
        2,
        "tsf diversity: Invalid value for '--games': -3 is outside the range 1 to 10000",
    ),
    ("eval --seeds 0", 2, "tsf eval: Invalid value for '--seeds': 0 is outside the range 1 to 10000"),
    (
        "eval --window 150 --window 0",
        2,
        "tsf eval: Invalid value for '--window': 0 is outside the range 1 to 108000",
    ),
    (
        "game --duration 1e9",
        2,
        "tsf game: Invalid value for '--duration': 1e9 is outside the range 0.1 to 3600.0",
    ),
    (
        "game --duration 1 --frames 30",
        2,
        "tsf game: --frames 30: give the length once: --duration (seconds) or --frames",
    ),
    ("sim --match x --duration 0", 2, "'--duration': 0 is outside the range 0.1 to 3600.0"),
    (
        "library add K {garbage} --role bait --games -1 --library {tmp}/lib",
        2,
        "tsf library add: Invalid value for '--games': -1 is outside the range 0 to 10000",
    ),
    ("eval --identify-seeds 1e6", 2, "'--identify-seeds': 1e6 is outside the range 1 to 10000"),
    ("eval --workers 9999", 2, "tsf eval: Invalid value for '--workers': 9999 is outside the range 0 to 256"),
    ("eval --strategy-window 1000000", 2, "'--strategy-window': 1000000 is outside the range 1 to 108000"),
    ("calibrate-adapter --workers 1e9", 2, "'--workers': 1e9 is outside the range 0 to 256"),
    ("report {done} --reference-games 1e9", 2, "'--reference-games': 1e9 is outside the range 1 to 10000"),
    (
        "replay {done} --speed inf",
        2,
        "tsf replay: Invalid value for '--speed': inf is outside the range 0.01 to 100.0",
    ),
    (
        "replay {done} --every 0",
        2,
        "tsf replay: Invalid value for '--every': 0 is outside the range 1 to 108000",
    ),
    (
        "replay {done} --delay -1",
        2,
        "tsf replay: Invalid value for '--delay': -1 is outside the range 0.0 to",
    ),
    (
        "alive --match x --service sim --timeout nan",
        2,
        "tsf alive: Invalid value for '--timeout': nan is outside",
    ),
    (
        "human --match x --port -1",
        2,
        "tsf human: Invalid value for '--port': -1 is outside the range 0 to 65535",
    ),
    (
        "study {tmp}/long.toml",
        2,
        "tsf study: CONFIG {tmp}/long.toml: not a study: trial_seconds 1000000000.0: outside the range 0.1",
    ),
    # Outputs: where nothing can be written is refused before the work starts.
    ("eval --out {garbage}", 2, "tsf eval: Invalid value for '--out': {garbage} is not a directory"),
    (
        "calibrate-adapter --out {tmp}",
        2,
        "tsf calibrate-adapter: Invalid value for '--out': {tmp} is a directory",
    ),
    (
        "sweep --out {garbage}/t.json",
        2,
        "tsf sweep: Invalid value for '--out': {garbage}/t.json: {garbage} is not a",
    ),
    (
        "train --out {garbage}",
        2,
        "tsf train: Invalid value for '--library' / '--out': {garbage} is not a directory",
    ),
    (
        "report {done} --out {garbage}",
        2,
        "tsf report: Invalid value for '--out': {garbage} is not a directory",
    ),
    ("match --out {garbage}", 2, "tsf match: Invalid value for '--out': {garbage} is not a directory"),
    ("table --plot {tmp}", 2, "tsf table: Invalid value for '--plot': {tmp} is a directory"),
    ("replay {done} --video {garbage}/m.gif", 2, "'--video': {garbage}/m.gif: {garbage} is not a directory"),
    (
        "export {done} --out {garbage}",
        2,
        "tsf export: Invalid value for '--out': {garbage} is not a directory",
    ),
    (
        "library add K {garbage} --role bait --library {garbage}",
        2,
        "tsf library add: Invalid value for '--library': {garbage} is not a directory",
    ),
]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    tmp = tmp_path_factory.mktemp("mistakes")
    done = tmp / f"{M}.tsflog"
    record_match(done)
    record_match(tmp / "tampered.tsflog", tamper=17)
    torn = tmp / "torn.tsflog"
    torn.write_bytes(done.read_bytes()[: done.stat().st_size // 2])
    (tmp / "garbage").write_text("this is no recording\n")
    (tmp / "empty.toml").write_text("")
    (tmp / "grown-other").mkdir()  # a grown library's run of another population spec
    (tmp / "grown-other" / "spec.json").write_text('{"population": "0123456789abcdef"}')
    study = (resources.files("services.study") / "configs" / "static.toml").read_text()
    (tmp / "long.toml").write_text(study.replace("trial_seconds = 60", "trial_seconds = 1e9"))
    (tmp / "typo.toml").write_text(study.replace("trial_seconds = 60", "trial_secnds = 60"))
    (tmp / "text.toml").write_text(f'{study}\n[crowd.bonus]\nper_kill = 0.1\nmax = "2"\n')
    (tmp / "s55.toml").write_text(study.replace('shooter = "S5"', 'shooter = "S55"'))
    (tmp / "static.toml").write_text(study)  # a good study: the options beside it are what is wrong
    (tmp / "spaced.toml").write_text(study.replace('name = "B4-S2"', 'name = "B1-S1 "'))
    (tmp / "blank-code.toml").write_text(f'{study}\n[crowd]\ncompletion_code = "   "\n')
    names = {"done": done, "torn": torn, "tampered": tmp / "tampered.tsflog", "garbage": tmp / "garbage"}
    return {"tmp": str(tmp), **{name: str(path) for name, path in names.items()}}


@pytest.fixture(autouse=True)
def signals_kept() -> Iterator[None]:
    """Commands install their signal handlers in this process: put pytest's back."""
    kept = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    yield
    for sig, handler in kept.items():
        signal.signal(sig, handler)


def tsf(args: list[str], capsys: pytest.CaptureFixture) -> tuple[int, list[str]]:
    """Run `tsf ARGS` in-process; its exit status and the lines it wrote to stderr."""
    status = run(app, args)
    return status, capsys.readouterr().err.splitlines()


# Mistakes found only once the command's extra is there: without it, its line is the extra's.
NEEDS_TRAIN = {"library grow --out {tmp}/grown-other", "library condition {tmp} --seat bait"}


@pytest.mark.parametrize(("line", "status", "said"), MISTAKES, ids=[m[0][:60] for m in MISTAKES])
def test_a_mistake_is_one_line_and_an_exit_status(
    line: str, status: int, said: str, files: dict[str, str], capsys: pytest.CaptureFixture
) -> None:
    if line in NEEDS_TRAIN and find_spec("stable_baselines3") is None:
        pytest.skip("the `train` extra is not installed")
    args = [a.format(**files) for a in shlex.split(line)]
    got, lines = tsf(args, capsys)
    assert (got, len(lines)) == (status, 1), lines
    assert said.format(**files) in lines[0] and "Traceback" not in lines[0]
    assert lines[0].startswith("tsf")


def test_enough_mistakes_are_tried() -> None:
    assert len(MISTAKES) >= 60 and len({m[0] for m in MISTAKES}) == len(MISTAKES)


def test_no_default_writes_into_the_checkout_or_the_package() -> None:
    """Every path a command defaults to is relative to the current directory and names none of the
    project's own directories: a shipped artifact (the table, the library, docs/eval) is written
    only when its path is given."""
    shipped = ("services", "shared", "docs")  # the packages and the pages with measured results
    defaults = {
        (name, param.name): param.default
        for name, command in typer.main.get_command(app).commands.items()
        for param in command.params
        if isinstance(param.default, Path)
    }
    assert defaults  # the walk sees them
    assert {k: p for k, p in defaults.items() if p.is_absolute() or p.parts[0] in shipped} == {}


def test_the_shipped_table_is_read_from_any_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.chdir(tmp_path)
    assert run(app, ["table"]) == 0
    assert "mean of the table" in capsys.readouterr().out and list(tmp_path.iterdir()) == []


def test_train_without_the_train_extra_says_which_extra(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.setitem(sys.modules, "torch", None)  # as if torch were not installed
    monkeypatch.delitem(sys.modules, "services.training.loop", raising=False)
    status, lines = tsf(["train", library.learned([])[0]], capsys)
    assert status == 1 and len(lines) == 1
    assert (
        lines[0]
        == f"tsf train: training needs the `train` extra (torch is not installed): {install_line('train')}"
    )


def test_debug_shows_the_traceback(files: dict[str, str], capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(UsageError, match="--bait B99"):
        run(app, ["game", "--bait", "B99", "--debug"])
    assert tsf(["game", "--bait", "B99"], capsys)[0] == 2


def test_no_command_shows_the_help(capsys: pytest.CaptureFixture) -> None:
    assert run(app, []) == 0
    assert "Team Space Fortress" in capsys.readouterr().out


def test_the_installed_command_is_the_entry(tmp_path: Path) -> None:
    """`tsf` on PATH (pyproject's script) goes through services.commands.entry too."""
    tsf_path = shutil.which("tsf", path=str(Path(sys.executable).parent))
    assert tsf_path is not None
    done = subprocess.run([tsf_path, "game", "--bait", "B99"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.startswith("tsf game: --bait B99") and not done.stdout


def test_a_bad_library_path_is_one_line_even_before_the_command_starts(tmp_path: Path) -> None:
    """The options' help lists the library's keys when the command line is built; a TSF_LIBRARY
    that names no library (misspelt, or a directory without a registry) is one line as any command
    starts, not a traceback, nor a later complaint about thresholds in a directory that is none."""
    tsf_path = shutil.which("tsf", path=str(Path(sys.executable).parent))
    assert tsf_path is not None
    (tmp_path / "empty").mkdir()
    missing = (
        "no such library; valid: grown, tuned, population, population-3, a directory with a registry.toml"
    )
    for value, said in [
        (tmp_path / "missing", missing),
        ("grwon", missing),
        (tmp_path / "empty", "is not a policy library (no registry.toml in it)"),
    ]:
        env = {**os.environ, "TSF_LIBRARY": str(value)}
        done = subprocess.run([tsf_path, "keys"], capture_output=True, text=True, timeout=60, env=env)
        assert done.returncode == 2 and not done.stdout
        assert done.stderr.splitlines() == [f"tsf keys: TSF_LIBRARY {value}: {said}"]


def test_an_adaptive_match_or_study_without_thresholds_for_the_library_stops_before_it_starts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    mine = empty_library(tmp_path / "mine")  # no thresholds either
    monkeypatch.setenv("TSF_LIBRARY", str(mine))
    out = tmp_path / "recordings"
    study = tmp_path / "study.toml"  # the study library's agent: the shipped configs play the grown one's
    study.write_text(
        'name = "x"\n[[variants]]\nname = "a"\nadapter = "adaptive-T400-bayes-dwell-ood-guard"\n'
    )
    said = "--strategy bayes-dwell-ood-guard: no out-of-library thresholds at"
    for command in (
        ["match", "--adaptive", "shooter", "--partners", "library", "--lockstep"],
        ["study", str(study)],
    ):
        status, lines = tsf([*command, "--out", str(out)], capsys)
        assert status == 2 and len(lines) == 1 and not out.exists()
        assert lines[0].startswith(f"tsf {command[0]}: ") and f"{said} {mine}" in lines[0]


def test_an_adaptive_match_on_groups_without_thresholds_stops_before_it_starts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """The grown library's agent reads its partner groups from the last library in use that has
    them: groups never calibrated are one line that says how to calibrate them."""
    mine = empty_library(tmp_path / "mine")
    grouped = json.loads((library.NAMED["grown"] / "groups.json").read_text())
    for seat in grouped["seats"].values():
        seat.pop("thresholds")
    (mine / "groups.json").write_text(json.dumps(grouped))
    monkeypatch.setenv("TSF_LIBRARY", str(mine))
    out = tmp_path / "recordings"
    status, lines = tsf(["match", "--adaptive", "shooter", "--lockstep", "--out", str(out)], capsys)
    assert status == 2 and len(lines) == 1 and not out.exists()
    assert (
        "no out-of-group thresholds: measure them with `tsf calibrate-adapter --partners groups" in lines[0]
    )


def test_a_study_is_checked_without_serving(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """`tsf study --check` is a lab's pre-flight: it says the study is ready, and starts and writes
    nothing; a config with a mistake is refused the same way, before anything is written."""
    out = tmp_path / "studies"
    for name in ("static", "adaptive"):
        study = str(resources.files("services.study") / "configs" / f"{name}.toml")
        status = run(app, ["study", study, "--check", "--out", str(out)])
        said = capsys.readouterr().out.replace("\n", " ")
        assert status == 0 and f"study {name}," in said and "ready to serve" in said and not out.exists()
    typo = tmp_path / "typo.toml"
    typo.write_text('name = "x"\n[[variants]]\nname = "a"\nbait = "B1"\nshooter = "S55"\n')
    status, lines = tsf(["study", str(typo), "--out", str(out)], capsys)
    assert status == 2 and len(lines) == 1 and "shooter = S55: no policy of the shooter seat" in lines[0]
    assert not out.exists()


@pytest.mark.parametrize("command", ["study", "play", "human"])
def test_a_busy_port_is_one_line_before_anything_starts(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A port another program listens on is refused at once, naming --port: no pool started, no
    study directory or bonuses.csv written."""
    study = str(resources.files("services.study") / "configs" / "static.toml")
    args = {"study": ["study", study, "--out", str(tmp_path / "s")], "play": ["play", "--out", str(tmp_path)]}
    with socket.create_server(("127.0.0.1", 0)) as busy:
        port = busy.getsockname()[1]
        line = [*args.get(command, ["human", "--match", "m"]), "--port", str(port)]
        status, lines = tsf(line, capsys)
    assert status == 2 and lines == [
        f"tsf {command}: --port {port}: in use by another program on 127.0.0.1: give another port"
    ]
    assert not (tmp_path / "s").exists() and list(tmp_path.iterdir()) == []


def test_a_plug_in_in_the_working_directory_loads(tmp_path: Path) -> None:
    """`my_lab/partners.py` in the working directory is found as docs/adapter.md shows it, by the
    installed `tsf` as by `python -m`."""
    tsf_script = Path(sys.executable).with_name("tsf")
    if not tsf_script.exists():
        pytest.skip("no installed tsf script beside this Python")
    (tmp_path / "my_lab").mkdir()
    (tmp_path / "my_lab" / "partners.py").write_text(
        "class Alice:\n    key, role, view = 'alice', 'bait', 'world'\n\n"
        "    def reset(self, seed=None): ...\n\n    def act(self, obs):\n        return 9\n"
    )
    done = subprocess.run(
        [str(tsf_script), "game", "--bait", "my_lab.partners:Alice", "--frames", "30"],
        cwd=tmp_path, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "game seed=0: 0 kills in 30 frames" in done.stdout


def test_an_unreachable_ray_address_is_one_line_within_seconds(tmp_path: Path) -> None:
    """Ray's client would retry for minutes: the address has REACH seconds to answer."""
    pytest.importorskip("ray", reason="the `ray` extra is not installed")
    from services.jobs.ray_engine import REACH

    command = [
        sys.executable,
        "-m",
        "services.commands",
        "sweep",
        "--ray",
        "127.0.0.1:1",
        "--out",
        str(tmp_path / "t.json"),
    ]
    started = time.monotonic()
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    took = time.monotonic() - started
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 1 and lines[-1].startswith(
        "tsf sweep: --ray 127.0.0.1:1: no Ray cluster reached"
    )
    assert took < REACH + 30  # the wait itself is REACH; the rest, importing Ray on a loaded machine


def test_calibrating_groups_into_a_file_that_is_no_groups_file_stops_before_it_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """`--partners groups` writes the thresholds into a groups file: any other --out (a library's
    calibration.json) is one line before a game is played, and is left as it was."""
    out = tmp_path / "calibration.json"
    out.write_text('{"thresholds": {}}')
    status, lines = tsf(["calibrate-adapter", "--partners", "groups", "--out", str(out)], capsys)
    assert status == 2 and len(lines) == 1 and "not a groups file" in lines[0]
    assert out.read_text() == '{"thresholds": {}}' and not (tmp_path / "calibration.json.journal").exists()
