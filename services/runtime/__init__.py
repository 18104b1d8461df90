"""The runtime floor: starting a match as processes (launch.py) and a pool of long-lived services
that play many matches each (pool.py). The packages that start matches (human, study, the command
line) stand on it; it stands on the agent, adapter and recorder it starts."""
