"""The partner population, below the adapter: what plays a seat (seat.py: `SeatSpec`), the partners
built from it (partners.py: library policies, wrappers, the human-like stand-ins of human_like.py
and their keystroke model in keys.py), the adaptive agent as a value (adaptive.py:
`AdapterConfig`), and the population a library is grown for, generated from a spec (families.py).
Training, the adapter, the evaluation, the launcher and the study all name seats through it."""
