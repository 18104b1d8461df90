"""A study's pre-flight: everything `tsf study` checks before it serves (and `tsf study --check`
alone), so that a lab's typo is one line at the start and never a participant's broken trial.

The config file's keys, kinds and values are checked as it is read (StudyConfig.load); here every
trial's match is checked as the server will start it: each variant's agent in each seat a
participant's role leaves to it, exactly as `tsf match` checks a seat (MatchPlan: a key that plays
the seat, a model or plug-in that loads and plays it, an adaptive agent's thresholds and name)."""

from __future__ import annotations

from pathlib import Path

from services.population.seat import AdaptiveSeat, PersonSeat, check_live
from services.runtime.launch import MatchPlan
from services.study.core import PRACTICE, StudyConfig, Variant
from shared.errors import UsageError
from shared.game import other


def load_checked(path: str | Path) -> StudyConfig:
    """The study of the TOML file at `path`, every match it will play checked; else a UsageError
    that names the file, the variant, the seat and what is accepted."""
    config = StudyConfig.load(path)
    variants = [*config.variants, *([Variant.read(*PRACTICE)] if config.practice_seconds else [])]
    for variant in variants:
        for role in config.roles:
            agent = other(role)
            spec = variant.seat(agent)
            try:
                if not isinstance(spec, AdaptiveSeat):  # the setting named as the file names it
                    check_live(spec, agent, f"{agent} =")
                MatchPlan("preflight", config.seed, config.frames, **{role: PersonSeat(), agent: spec})
            except UsageError as error:
                problem = f"not a study: variant {variant.name} (the {agent} seat): {error}"
                raise UsageError("CONFIG", path, problem) from None
    return config
