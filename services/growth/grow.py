"""`tsf library grow`: a library grown for coverage, from a partner population to a named library.

The pipeline, one module a stage, each stage's result written to the output directory when it is
done, so that a run killed at any point resumes where it stopped (a stage's jobs from the engine's
journal, a training from its checkpoint); workspace.py holds what the stages share.

1. population  population.py: the spec's members per seat, the events runs trained to each level.
2. grouping    crossplay.py: the training members with the candidate teammates of the other seat.
3. groups      groups.py: the training members grouped by what works with them.
4. responses   responses.py: one best response per group (the spec's algorithm), against its
               members and stand-ins; where the spec asks, first imitating the group's best rule.
5. held-out    crossplay.py: the validation and test members, with their stand-ins, with every
               candidate: the study's policies, the rules and the responses.
6. search      search.py: where the spec asks for it, our seat's rule tuned by search (Optuna's TPE)
               per partner group and over the whole training population; each study's best setting
               played with the held-out partners, a column of the held-out grids beside the rest.
7. selection   selection.py: per seat, the greedy coverage selection on the validation population.
8. library     library.py: the selected members under keys of their own (GB1.., GS1..), the table,
               the adapter's calibration, the partner groups; summary.py: the test population's figures.
"""

from __future__ import annotations

from services.growth import library
from services.growth.choice import Grid
from services.growth.crossplay import crossplay
from services.growth.groups import groups
from services.growth.population import population
from services.growth.responses import responses
from services.growth.search import search
from services.growth.selection import selection
from services.growth.summary import summary
from services.growth.workspace import KINDS, Workspace
from shared.game import ROLES

__all__ = ["KINDS", "Grow"]


class Grow(Workspace):
    """One run of the pipeline over an output directory (see the module docstring)."""

    def run(self) -> dict:
        """The stages in turn (each read back where it is done); the test population's figures."""
        self.bind()
        members = self.timed("population", population)
        train = {r: self.side(members[r], "train", stand_ins=False) for r in ROLES}
        grouping = self.timed("grouping", crossplay, "grouping", train)
        grouped = self.timed("groups", groups, grouping)
        self.timed("responses", responses, grouped, grouping)
        held = {r: self.side(members[r], "validation") + self.side(members[r], "test") for r in ROLES}
        held_out = self.timed("held-out", crossplay, "held-out", held)
        held_out = self.timed("search", search, grouped, held_out)
        selected = self.timed("selection", selection, held_out)
        return self.timed("library", _library, selected, held_out, grouped, grouping)


def _library(
    ws: Workspace, selected: dict, held_out: dict[str, Grid], grouped: dict, grouping: dict[str, Grid]
) -> dict:
    """The grown library, built once, and its figures, computed from the files each time."""
    library.build(ws, selected, held_out, grouped, grouping)
    return summary(ws, selected, held_out, grouped, grouping)
