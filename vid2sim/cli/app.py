"""`vid2sim` command line: one typer sub-app per subsystem.

Every command that reports data takes `--json`. Only commands that work are registered.
User errors follow one convention (`vid2sim.cli.errors`): exit 2, one line naming the input.
"""

from __future__ import annotations

import typer

from vid2sim.cli.errors import ConventionGroup

app = typer.Typer(
    name="vid2sim",
    help="Video-to-simulation data factory for robot navigation.",
    no_args_is_help=True,
    pretty_exceptions_show_locals=False,
    cls=ConventionGroup,
)


def _register_subapps() -> None:
    """Each subsystem adds one import + add_typer line here."""
    from vid2sim.bullet import import_pybullet
    import_pybullet()  # before any module imports it plainly, so no command prints its build-time banner
    from vid2sim.cli.config import app as config_app
    app.add_typer(config_app, name="config")
    from vid2sim.cli.registry import app as registry_app
    app.add_typer(registry_app, name="registry")
    from vid2sim.cli.eval import app as eval_app
    app.add_typer(eval_app, name="eval")
    from vid2sim.cli.sfm import app as sfm_app
    app.add_typer(sfm_app, name="sfm")
    from vid2sim.cli.ingest import ingest_command
    app.command("ingest")(ingest_command)
    from vid2sim.cli.recon import app as recon_app
    app.add_typer(recon_app, name="recon")
    from vid2sim.cli.train import study_command, train_command
    app.command("train")(train_command)
    app.command("study")(study_command)
    from vid2sim.cli.ensemble import ensemble_command
    app.command("ensemble")(ensemble_command)
    from vid2sim.cli.envs import app as envs_app
    app.add_typer(envs_app, name="envs")
    from vid2sim.cli.view import view_command
    app.command("view")(view_command)


@app.command()
def version() -> None:
    """Print the code version."""
    from vid2sim.versioning import code_version

    typer.echo(code_version())


@app.command()
def demo(
    registry: str = typer.Option(None, "--registry",
                                 help="Registry root (default $VID2SIM_REGISTRY or ./vid2sim-registry)."),
    workdir: str = typer.Option("vid2sim-work", "--workdir", help="Work folder for stage outputs."),
) -> None:
    """Run the main job end to end on embedded defaults (no downloaded data), then one episode of
    the scripted expert in the new scene, and print how to open both in the browser viewer."""
    from vid2sim.cli.demo import finish_demo
    from vid2sim.cli.inputs import creatable_folder
    from vid2sim.factory.runtime.demo import run_demo

    creatable_folder(registry, "--registry")
    creatable_folder(workdir, "--workdir")
    summary = run_demo(registry=registry, workdir=workdir)
    finish_demo(summary["scene_id"], registry, workdir, typer.echo)


_register_subapps()


def main() -> None:
    app()


if __name__ == "__main__":
    main()
