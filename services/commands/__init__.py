"""The `tsf` command line, the top layer: one module per group of commands (`app.py` joins them,
`options.py` holds the options they share, `entry.py` ends a command in one line). The packages
below keep their pure functions and name no command; `python -m services.commands` is `tsf`."""
