"""``rfidstudy scenes list`` and ``rfidstudy scenes show``: the bundled scenes
(:data:`scenes_app`, added to :data:`pipeline.apps.cli.app` as ``scenes``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

import scenes
from pipeline.apps.clicommon import WRITE_ERRNOS, fail, fail_os
from pipeline.robot import Robot
from pipeline.studyscene import map_route
from scenes.mapsites import describe_map_scene

__all__ = ["scenes_app"]

scenes_app = typer.Typer(no_args_is_help=True, help="Bundled scenes.")


@scenes_app.command("list")
def scenes_list():
    """List the bundled scenes."""
    for name in scenes.list_bundled():
        typer.echo(name)


@scenes_app.command("show")
def scenes_show(
    name: Annotated[str, typer.Argument(help="Bundled scene name or scene path.")],
    png: Annotated[Path | None, typer.Option(
        help="Write a top-view picture here (a .png file; nothing else is written).")] = None,
):
    """Describe a scene (size, materials, tags) and optionally draw its top view."""
    if png is not None and png.suffix.lower() != ".png":
        fail(f"--png {png}: the top view is written as PNG; give a file name ending in .png")
    if png is not None and png.is_dir():
        fail(f"--png {png}: is a directory; give a file name ending in .png")
    if png is not None and any(p.exists() and not p.is_dir() for p in png.parents):
        fail(f"--png {png}: a file stands where its folder would be")
    try:
        sc = scenes.load(name)
    except (FileNotFoundError, KeyError, ValueError) as exc:
        fail(str(exc))
    route_note = ""
    if sc.route_m is None and scenes.sources.traits_of(sc).plans_route:  # a map: the route a study would plan
        try:
            sc = map_route(sc, Robot())
        except ValueError as exc:  # shown, not fatal: the map itself is fine to look at
            route_note = f"  route: none planned ({exc})"
    lo, hi = sc.bounds_m
    typer.echo(f"scene {sc.name} ({sc.source})")
    typer.echo(f"  bounds: x {lo[0]:.2f}..{hi[0]:.2f} m, y {lo[1]:.2f}..{hi[1]:.2f} m, "
               f"z {lo[2]:.2f}..{hi[2]:.2f} m")
    typer.echo(f"  materials: {', '.join(sc.materials)}")
    typer.echo(f"  tags: {len(sc.tags)}")
    if sc.route_m is not None:
        typer.echo(f"  route: {len(sc.route_m)} points")
    elif route_note:
        typer.echo(route_note)

    for line in describe_map_scene(sc):
        typer.echo(line)
    typer.echo(f"  content hash: {sc.content_hash()[:16]}")
    if png is not None:
        from pipeline.stages import draw_scene_top_view  # lazy: start-up time

        try:
            typer.echo(f"  top view: {draw_scene_top_view(sc, png)}")
        except OSError as exc:
            if exc.errno not in WRITE_ERRNOS:
                raise
            fail_os(exc, str(png))
