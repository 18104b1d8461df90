"""Growing a library for coverage: the population's cross-play, its groups, a best response per
group, and the members that leave an adaptive teammate the most room (`tsf library grow`)."""
