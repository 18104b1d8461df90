"""The stand-ins' calibration table, and the evidence of what kept them from scoring (docs/humans.md).

(a) The calibration: pairs of stand-ins (`human(Bk)` with `human(S)`, S the table's best shooter
for Bk), a bait stand-in with that library shooter, a shooter stand-in with its best library
bait; per skill (novice, typical, practised), kills/min with standard errors over teams x seeds,
against the study's human pairs (2.6).
(b) With --learning: the pairs over a whole study (`session=15`: fifteen one-minute trials of one
person, practice carrying over), kills/min per trial by skill.
(c) With --evidence: library pairs (each bait with its best shooter) with a pure delay of 0-8
frames on the shooter, the bait or both (`delayed(K,frames=d)`); and the library pairs and the
typical stand-in pairs under the rule numbers marked *(assumption)* on docs/rules.md, varied.

    .venv/bin/python bench/humans.py [--seeds 12] [--learning PEOPLE] [--evidence]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from services.agent import library
from services.evaluation.evaluate import play_teams
from services.population.human_like import SKILLS
from services.population.seat import seats_of
from services.proxy.humans import STUDY_PAIRS, calibration
from services.table.table import Table
from shared.game import GameConfig

DELAYS = (0, 1, 2, 3, 4, 6, 8)  # frames
RULES = {  # the assumption numbers of docs/rules.md, varied one at a time
    "default": {},
    "vulnerable_frames=30": {"vulnerable_frames": 30},
    "vulnerable_frames=40": {"vulnerable_frames": 40},
    "fortress_turn=2": {"fortress_turn": 2.0},
    "missile_cooldown=3": {"missile_cooldown": 3},
}


def mean_se(kills: np.ndarray) -> str:
    scores = kills.ravel()
    return f"{scores.mean():5.2f} ± {scores.std(ddof=1) / np.sqrt(len(scores)):.2f}"


def evidence(seeds: list[int]) -> None:
    table = Table.load()
    pairs = [(b, table.best_shooter(b)) for b in library.keys("bait")]
    seats = {
        "shooter": lambda b, s, d: (b, f"delayed({s},frames={d})"),
        "bait": lambda b, s, d: (f"delayed({b},frames={d})", s),
        "both": lambda b, s, d: (f"delayed({b},frames={d})", f"delayed({s},frames={d})"),
    }
    print(f"\nlibrary pairs (each bait with its best shooter), a pure delay ({len(seeds)} seeds)")
    print(f"{'delay':>14s}" + "".join(f"{seat:>18s}" for seat in seats))
    for d in DELAYS:
        cells = [
            mean_se(play_teams([seats_of(team(b, s, d)) for b, s in pairs], seeds)) for team in seats.values()
        ]
        print(f"{d:3d} fr {d * 1000 / 30:4.0f} ms" + "".join(f"{c:>18s}" for c in cells))
    humans = [(f"human({b})", f"human({s})") for b, s in pairs]
    print(f"\nthe rule numbers marked (assumption), varied ({len(seeds)} seeds)")
    print(f"{'rules':>22s}{'library pairs':>18s}{'typical stand-ins':>20s}")
    for name, changes in RULES.items():
        config = GameConfig().replace(**changes)
        cells = [mean_se(play_teams(list(map(seats_of, teams)), seeds, config)) for teams in (pairs, humans)]
        print(f"{name:>22s}{cells[0]:>18s}{cells[1]:>20s}")


STUDY_TRIALS = 15  # a study's session: fifteen one-minute trials


def learning(people: int) -> None:
    """Each skill's pairs (every bait with its table-best shooter, both stand-ins of that skill,
    in sessions of STUDY_TRIALS), `people` people each: kills/min per trial, over teams x people."""
    table = Table.load()
    pairs = [(b, table.best_shooter(b)) for b in library.keys("bait")]
    seeds = list(range(people * STUDY_TRIALS))  # seed s: trial s % 15 of person s // 15
    print(f"\npairs over a study of {STUDY_TRIALS} trials ({len(pairs)} teams x {people} people per cell)")
    print(f"{'trial':>6s}" + "".join(f"{skill:>16s}" for skill in SKILLS))
    kills = {}
    for skill in SKILLS:
        person = f"skill={skill},session={STUDY_TRIALS}"
        teams = [(f"human({b},{person})", f"human({s},{person})") for b, s in pairs]
        kills[skill] = play_teams(list(map(seats_of, teams)), seeds).reshape(len(pairs), people, STUDY_TRIALS)
    for trial in range(STUDY_TRIALS):
        cells = [mean_se(k[:, :, trial]) for k in kills.values()]
        print(f"{trial + 1:6d}" + "".join(f"{c:>16s}" for c in cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12, help="game seeds per team (3 trials per person)")
    parser.add_argument("--learning", type=int, metavar="PEOPLE", help="also the pairs over a 15-trial study")
    parser.add_argument("--evidence", action="store_true", help="also the delay and rule measurements")
    parser.add_argument("--no-calibration", action="store_true", help="only what the other options ask for")
    args = parser.parse_args()
    began = time.monotonic()
    if not args.no_calibration:
        print(f"stand-ins' kills/min ({args.seeds} seeds per team; the study's human pairs: {STUDY_PAIRS})")
        print(f"{'skill':>10s}{'pairs':>16s}{'bait stand-in':>18s}{'shooter stand-in':>20s}")
        rows = calibration(seeds=args.seeds)
        for skill in dict.fromkeys(r.skill for r in rows):
            cells = [f"{r.mean:5.2f} ± {r.stderr:.2f}" for r in rows if r.skill == skill]
            print(f"{skill:>10s}{cells[0]:>16s}{cells[1]:>18s}{cells[2]:>20s}")
    if args.learning:
        learning(args.learning)
    if args.evidence:
        evidence(list(range(args.seeds)))
    print(f"\n{time.monotonic() - began:.0f} s")


if __name__ == "__main__":
    main()
