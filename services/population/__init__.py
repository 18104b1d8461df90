"""The partner population: who an adaptive teammate may meet, generated from a spec (families.py)."""
