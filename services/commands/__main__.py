"""`python -m services.commands`: the `tsf` command, as the services' launchers start it."""

from services.commands.app import main

main()
