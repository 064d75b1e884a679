"""``regrasp robot list | urdf NAME | info NAME [--json]``."""

from __future__ import annotations

import math

import click
from rich.table import Table

from .common import console, err_console, fail, print_json


@click.group()
def robot() -> None:
    """Robot models: list them, print a URDF path, describe one."""


@robot.command("list")
def list_robots() -> None:
    """Print the available robots, one per line."""
    from planner.api.catalogue import DEFAULT_ROBOT, load_spec, robot_names

    from planner.errors import InputError

    for name in robot_names():
        mark = " (default)" if name == DEFAULT_ROBOT else ""
        try:
            description = load_spec(name).description
        except InputError as exc:  # e.g. a model package that is not installed
            description = f"(unavailable: {exc})"
        click.echo(f"{name}{mark}\t{description}")


@robot.command("urdf")
@click.argument("name")
def urdf(name: str) -> None:
    """Print the absolute path of NAME's URDF (loads in pinocchio with a free-flyer root): the derived URDF (the
    spec's frames added, mesh collisions fitted) when the robot's own needs that, else its own."""
    from planner.api.catalogue import urdf_path
    from planner.errors import InputError

    try:
        click.echo(str(urdf_path(name)))
    except InputError as exc:
        fail(str(exc))


@robot.command("check")
@click.argument("spec_file", type=click.Path(dir_okay=False))
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False),
              help="Draw each built-in stance's feet, support polygon and CoM to this image (png, svg, pdf).")
@click.option("--quiet", is_flag=True, help="No progress lines on stderr.")
def check(spec_file: str, plot_path: str | None, quiet: bool) -> None:
    """Validate a robot spec file (regrasp.robot/1) and print what was derived from its URDF: frames, chains,
    limits, the self-collision matrix (computed without an SRDF, cached), the pairs in collision at the ready
    posture and the stances, and the ready posture to paste into the spec when it gives none."""
    import time

    from planner.api.robots import derive_spec_file as derive
    from planner.errors import InputError

    started = time.monotonic()

    def progress(message: str) -> None:
        if not quiet:
            err_console.print(f"[dim]{time.monotonic() - started:5.1f} s  {message}[/]", highlight=False)

    progress("reading the spec and its URDF")
    try:
        d = derive(spec_file, progress)
    except InputError as exc:
        fail(str(exc))
    s = d.spec
    console.print(f"[bold]{s.name}[/]: valid", highlight=False)
    console.print(f"URDF {d.urdf}", highlight=False, soft_wrap=True)
    if d.urdf_as_is:
        console.print("derived URDF: none (the URDF is used as it is)", highlight=False)
    else:
        console.print(f"derived URDF {d.derived_urdf}", highlight=False, soft_wrap=True)
    console.print(f"frames created: {', '.join(d.created_frames) or 'none (all in the URDF)'}", highlight=False)
    for side, foot in s.feet.items():
        console.print(f"{side} leg ({foot.frame}): {', '.join(foot.chain)}", highlight=False)
    for side, arm in s.arms.items():
        hand = ("rigid hand (the object attaches at the TCP)" if arm.gripper is None else
                f"jaw {arm.gripper.joint} 0..{arm.gripper.max_opening_m * 1000:.1f} mm")
        console.print(f"{side} arm ({arm.tcp}): {', '.join(arm.chain)}; {hand}", highlight=False)
    console.print(f"waist: {', '.join(s.waist) or '-'}; neck: {', '.join(s.neck) or '-'}"
                  + (f"; hand joints: {', '.join(s.hand_joints)}" if s.hand_joints else ""), highlight=False, soft_wrap=True)
    by_source: dict[str, list[str]] = {}
    for joint, source in d.limit_sources.items():
        by_source.setdefault(source, []).append(joint)
    for source, joints in by_source.items():
        console.print(f"effort limits from {source}: {', '.join(joints)}", highlight=False)
    for note in d.notes or ("collision: the URDF's primitives",):
        console.print(note, highlight=False, soft_wrap=True)
    _check_model(spec_file, plot_path, progress, posture_given=bool(s.default_posture_rad))


def _pairs(pairs) -> str:  # type: ignore[no-untyped-def]
    return ", ".join(f"{a}/{b}" for a, b in pairs) or "none"


def _check_model(spec_file: str, plot_path: str | None, progress, posture_given: bool) -> None:  # type: ignore[no-untyped-def]
    """The model-level part of ``robot check``: ready posture, collision matrix, collisions, feet."""
    from planner.api.robots import load_robot, robot_report
    from planner.errors import InputError

    progress("loading the model (and the ready posture)")
    try:
        robot = load_robot(spec_file)
        report = robot_report(robot, progress)
    except (InputError, ValueError) as exc:
        fail(str(exc))
    if not posture_given:
        derived = robot.spec.default_posture_rad
        if derived:
            values = ", ".join(f"{joint}: {value!r}" for joint, value in derived.items())
            console.print("ready posture: derived, the spec gives none (arms down, hands clear; paste it into the "
                          f"spec to keep it):\ndefault_posture_rad: {{{values}}}", highlight=False, soft_wrap=True)
        else:
            console.print("ready posture: the zero posture (the spec gives none; its arms already hang down, clear "
                          "of the body)", highlight=False, soft_wrap=True)
    if report.ready_com_offset_m is not None:
        dx, dy = 1000 * report.ready_com_offset_m
        console.print(f"ready posture: CoM {dx:+.1f} mm forward, {dy:+.1f} mm left of its soles' polygon centre "
                      f"(pelvis upright at {robot.spec.upright.pelvis_height_m:.3f} m, soles "
                      f"{math.degrees(report.ready_sole_tilt_rad):.2f} deg from flat)", highlight=False, soft_wrap=True)
    m = report.matrix
    if m is None:
        console.print(f"collision matrix: the SRDF's ({report.spec_pairs} pairs with the spec's own)", highlight=False)
    else:
        console.print(f"collision matrix: computed over {m.samples} random configurations (seed {m.seed})"
                      f"{' (cached)' if report.matrix_cached else ''}: not checked {len(m.adjacent)} adjacent, "
                      f"{len(m.always)} always in collision, {len(m.nested)} nested, {len(m.never)} never in "
                      f"collision" + (f"; {report.spec_pairs} more from the spec" if report.spec_pairs else ""),
                      highlight=False, soft_wrap=True)
        for label, pairs in (("always in collision", m.always), ("nested (one chain, often in collision)", m.nested),
                             ("never in collision", m.never)):
            console.print(f"  {label}: {_pairs(pairs)}", highlight=False, soft_wrap=True)
    for where, pairs in report.colliding.items():
        mark = "" if not pairs else " [yellow](not checked while planning: fix the posture or the shapes if real)[/]"
        console.print(f"in collision at the {where}: {_pairs(pairs)}{mark}", highlight=False, soft_wrap=True)
    for name, error in report.stance_errors.items():
        console.print(f"stance {name}: does not solve ({error})", highlight=False, soft_wrap=True)
    for fp in report.footprints:
        centre = fp.polygon.mean(axis=0) if len(fp.polygon) else fp.com[:2]
        console.print(f"stance {fp.stance}: CoM margin {fp.margin_m * 1000:.1f} mm, CoM {1000 * (fp.com[0] - centre[0]):+.1f} "
                      f"mm forward, {1000 * (fp.com[1] - centre[1]):+.1f} mm left of the polygon's centre", highlight=False,
                      soft_wrap=True)
    if plot_path:
        from experiments.footprint_plot import plot_footprints

        console.print(f"plot {plot_footprints(robot.name, report.footprints, plot_path)}", highlight=False, soft_wrap=True)


@robot.command("info")
@click.argument("name", default="hrp5p")
@click.option("--json", "as_json", is_flag=True, help="Print machine-readable JSON.")
def info(name: str, as_json: bool) -> None:
    """Describe a robot: mass, height, joints, limits and built-in stances."""
    from planner.api.robots import load_robot, robot_info
    from planner.errors import InputError

    try:
        doc = robot_info(load_robot(name))
    except InputError as exc:
        fail(str(exc))
    if as_json:
        print_json(doc)
        return
    console.print(f"[bold]{doc['name']}[/]: {doc['description']}")
    console.print(f"URDF {doc['urdf']}\nsha256 {doc['urdf_sha256']}")
    console.print(f"mass {doc['total_mass_kg']:.2f} kg, height {doc['height_m']:.3f} m, {doc['dof']} DoF")
    table = Table("joint", "lower rad", "upper rad", "vel rad/s", "acc rad/s^2")
    for j in doc["joint_names"]:
        lo, hi = doc["position_limits"][j]
        table.add_row(j, f"{lo:.3f}", f"{hi:.3f}", f"{doc['velocity_limits'][j]:.2f}", f"{doc['acceleration_limits'][j]:.2f}")
    console.print(table)
    st = Table("stance", "CoM x, y, z (m)", "margin (mm)")
    for s in doc["stances"]:
        if "error" in s:
            st.add_row(s["name"], "-", s["error"])
        else:
            st.add_row(s["name"], ", ".join(f"{v:.3f}" for v in s["com"]), f"{s['margin_m'] * 1000:.1f}")
    console.print(st)
    console.print(f"[dim]{doc['limit_sources']}[/]")
