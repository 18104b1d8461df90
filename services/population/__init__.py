"""The partner population, below the adapter: what plays a seat (seat.py: `SeatSpec`), the partners
built from it (partners.py: library policies, wrappers, the human-like stand-ins of human_like.py
and their keystroke model in keys.py) and the adaptive agent as a value (adaptive.py:
`AdapterConfig`). Training, the adapter, the evaluation, the launcher and the study all name seats
through it."""
