"""The runtime floor: starting a match as processes (launch.py) and child processes that never
outlive their launcher (processes.py). The packages that start matches or workers (human, study,
proxy, jobs, the command line) stand on it; it stands on the agent, adapter and recorder it starts."""
