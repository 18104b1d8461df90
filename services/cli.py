"""The `tsf` command line."""
import typer

app = typer.Typer(no_args_is_help=True, help="Team Space Fortress.")
