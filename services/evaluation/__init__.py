"""The evaluation, above the adapter: games of the adaptive agent and static policies with a
population of partners, in bulk (evaluate.py), and what is measured on them: identification,
team performance, the out-of-library thresholds, the skill table, the results and figures."""
