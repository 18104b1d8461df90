"""Growing a library for coverage: the population's cross-play, its groups, a best response per
group, and the members that leave an adaptive teammate the most room (`tsf library grow`)."""

# The job kinds the growth hands out, by name only: a worker imports a runner when first asked for
# one, so that a worker that never trains never loads torch (the `train` extra).
KINDS = {
    "pairs": "services.growth.crossplay:run_pair_jobs",
    "train": "services.growth.training:run_train_jobs",
}
