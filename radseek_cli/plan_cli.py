"""``radseek plan``: plan the next dwell point(s) for a map and a source belief; print and plot them.

The map (walls, x-y bounds) comes from a scene file (``--scene``, read through
``detector_fw_sim.scene.load_scene`` for walls and bounds only: never its sources), a dataset's
scenario.json (``--dataset``) or, with neither, the default scene. The belief and the previous dwell
points are given on the command line.

Examples::

    radseek plan --source 5,4,0 --sigma 0.3 --cps 2000 --dwell 1,1,1.5,40 --dwell 3,1,1.5,90 --plot plan.png
    radseek plan --scene detector_fw_sim/scenes/lattice-wall.toml --method explore --json
    radseek plan --fig4 docs/fig4-replica.png
    radseek plan --method lawnmower --export-plan search.plan    # open in QGroundControl

With no arguments it plans an exploration of the default scene (``next-best`` needs a belief,
``--source``). ``--export-plan`` writes the plan as a QGroundControl .plan file: takeoff, the
collision-free path as pass-through waypoints, each dwell point as a waypoint holding
``--export-dwell`` s facing its detector yaw, landing; the map's x-y bounds as an inclusion geofence and
each mapped wall (grown by ``--radius``) as an exclusion fence.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from planner import baselines
from planner.belief import DwellHistory, SourceBelief
from planner.dwell_tree import TreeConfig, grow_tree, seed_ompl
from planner.exploration import FrontierConfig, plan_exploration
from planner.next_best import NextBestConfig, plan_next_dwell, score_nodes
from planner.occupancy import OccupancyMap
from planner.plan import DwellPlan

METHODS = ("next-best", "explore", "lattice", "lawnmower", "spiral", "greedy")


def _floats(text: str, n: int, what: str) -> np.ndarray:
    try:
        v = np.array([float(a) for a in text.split(",")])
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what}: {text!r} is not {n} comma-separated numbers") from None
    if len(v) != n:
        raise argparse.ArgumentTypeError(f"{what}: expected {n} numbers, got {len(v)}")
    return v


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="radseek plan", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group()
    src.add_argument("--scene", type=Path, help="scene file (TOML/JSON): walls and bounds only")
    src.add_argument("--dataset", type=Path, help="dataset directory: its scenario.json's walls and bounds")
    p.add_argument("--method", choices=METHODS,
                   help="planner (default next-best with --source, else explore)")
    p.add_argument("--start", type=lambda s: _floats(s, 4, "--start"), help="x,y,z,yaw of the vehicle now")
    p.add_argument("--source", type=lambda s: _floats(s, 3, "--source"), help="belief mean x,y,z (m)")
    p.add_argument("--sigma", type=float, default=0.3, help="belief std per axis (m), default 0.3")
    p.add_argument("--cps", type=float, default=1000.0, help="belief net cps at 1 m, default 1000")
    p.add_argument("--background", type=float, help="background cps (default: the map's)")
    p.add_argument("--dwell", type=lambda s: _floats(s, 4, "--dwell"), action="append", default=[],
                   help="previous dwell point x,y,z,rate_cps (repeat)")
    p.add_argument("--flight-z", type=lambda s: _floats(s, 2, "--flight-z"), default=np.array([0.5, 2.5]),
                   help="min,max flight altitude (m), default 0.5,2.5")
    p.add_argument("--radius", type=float, default=0.3, help="vehicle radius (m), default 0.3")
    p.add_argument("--nodes", type=int, default=500, help="tree nodes N_max, default 500")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--plot", type=Path, help="write a PNG of the map, tree and plan")
    p.add_argument("--json", action="store_true", help="print the radseek.topics.Plan payload as JSON")
    p.add_argument("--fig4", type=Path, metavar="PNG", nargs="?", const=Path("runs/fig4-replica.png"),
                   help="only write the paper 003 Fig. 4 replica (default runs/fig4-replica.png) and exit")
    p.add_argument("--export-plan", type=Path, metavar="FILE", help="write the plan as a QGroundControl .plan")
    p.add_argument("--export-dwell", type=float, default=60.0, help="hold per dwell point in the .plan, s (60)")
    p.add_argument("--home", default="47.397742,8.545594,488.0",
                   help="home lat,lon,alt_amsl of the local frame, for --export-plan (default PX4 SITL's)")
    return p


def export_plan(path: Path, plan: DwellPlan, occ: OccupancyMap, home_text: str, dwell_s: float) -> Path:
    """The plan as a QGC .plan: takeoff, path via points, dwell waypoints, land; bounds as a fence."""
    from mission.client.mission_upload import DwellPoint, build_items, waypoint
    from mission.qgc_plan import write_plan
    from radseek.coordinates import Home, enu_to_geodetic

    lat, lon, alt = (float(v) for v in home_text.split(","))
    home = Home(lat, lon, alt)
    points = [DwellPoint(*map(float, d[:3]), yaw=float(d[3]), max_dwell_s=dwell_s) for d in plan.dwell_points]
    first_z = float(plan.path[0, 2]) if len(plan.path) else float(plan.dwell_points[0, 2])
    items = build_items([], home, takeoff_alt=max(first_z, 0.5))
    for q in plan.path[1:-1] if len(plan.path) > 2 else []:  # the path to the first dwell point: no stops
        items.append(waypoint(len(items), home, *map(float, q[:3])))
    for pt in points:
        items.append(waypoint(len(items), home, pt.x, pt.y, pt.z, pt.max_dwell_s, pt.yaw))
    items += build_items([], home, finish="land")
    # the vehicle reads a LAND at 0, 0 as "land where you are"; a .plan shows it there, at Null Island: give it
    # the last point's position (where the vehicle is when it lands)
    items[-1].x, items[-1].y = items[-2].x, items[-2].y
    for k, it in enumerate(items):
        it.seq = k
    lo, hi = occ.bounds_min, occ.bounds_max
    corners = [enu_to_geodetic(home, (x, y, 0.0))[:2] for x, y in ((lo[0], lo[1]), (hi[0], lo[1]),
                                                                    (hi[0], hi[1]), (lo[0], hi[1]))]
    polygons = [(True, corners)]
    from vehicle_sim.geofence import wall_zones  # the mapped walls as exclusion fences (QGC draws them)

    for z in wall_zones(occ.walls, occ.radius):
        polygons.append((False, [enu_to_geodetic(home, (x, y, 0.0))[:2] for x, y in z.vertices]))
    return write_plan(path, items, home, polygons=polygons)


def _load_map(args: argparse.Namespace) -> tuple[OccupancyMap, float]:
    if args.dataset is not None:
        from radseek_io.dataset import read_scenario

        scenario = read_scenario(args.dataset / "scenario.json")
    else:
        from detector_fw_sim.scene import load_scene  # walls and bounds only: sources are never read

        scenario = load_scene(args.scene).scenario()
    occ = OccupancyMap.from_scenario(scenario, args.radius, (float(args.flight_z[0]), float(args.flight_z[1])))
    return occ, float(scenario.background_cps)


def plot_fig4(path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from planner.fig4 import FIG4_DWELLS, FIG4_GAIN, FIG4_SOURCE, fig4_grid

    xs, ys, g, best = fig4_grid(13)  # 0.25 m spacing: the candidates shown are the ones evaluated
    fig = plt.figure(figsize=(10, 4.5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    gx, gy = np.meshgrid(xs, ys)
    ax.plot_surface(gx, gy, g, cmap="viridis", alpha=0.85)
    ax.set(xlabel="x (m)", ylabel="y (m)", zlabel="Gain (eq. 6)")
    ax2 = fig.add_subplot(1, 2, 2)
    im = ax2.contourf(gx, gy, g, levels=20, cmap="viridis")
    fig.colorbar(im, ax=ax2, label="Gain (eq. 6)")
    ax2.plot(gx, gy, "bx", ms=3)
    ax2.plot(*FIG4_SOURCE[:2], "ro", ms=9, label="source estimate")
    ax2.plot(FIG4_DWELLS[:, 0], FIG4_DWELLS[:, 1], "kx", ms=10, mew=2, label="previous dwell points")
    ax2.plot(*best[:2], "gv", ms=11, label="next best dwell point")
    ax2.set(xlabel="x (m)", ylabel="y (m)", aspect="equal",
            title=f"delta = {FIG4_GAIN.delta:g} m, zeta = {FIG4_GAIN.zeta:g}")
    ax2.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, fontsize=7)
    fig.suptitle("Paper 003 Fig. 4 setting: eq. 6 on a 3 x 3 m grid")
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def _plot(path: Path, occ: OccupancyMap, plan: DwellPlan, history: DwellHistory, belief: SourceBelief | None,
          tree_xy: tuple[np.ndarray, np.ndarray] | None, node_gain: np.ndarray | None, nodes: np.ndarray | None
          ) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6))
    xs, ys, occupied = occ.grid(0.1, float(plan.path[-1, 2]) if plan.ok else float(occ.bounds_min[2]))
    ax.pcolormesh(xs, ys, occupied, cmap="Greys", alpha=0.35, shading="nearest")
    for w in occ.walls:
        ax.plot([w.start[0], w.end[0]], [w.start[1], w.end[1]], "k-", lw=3)
    if tree_xy is not None:
        a, b = tree_xy
        ax.plot(np.c_[a[:, 0], b[:, 0]].T, np.c_[a[:, 1], b[:, 1]].T, "-", color="0.75", lw=0.5)
    if node_gain is not None and nodes is not None:
        sc = ax.scatter(nodes[:, 0], nodes[:, 1], c=node_gain, s=8, cmap="viridis")
        fig.colorbar(sc, ax=ax, label="Gain (eq. 6)")
    if len(history):
        ax.plot(history.positions[:, 0], history.positions[:, 1], "kx", ms=10, mew=2, label="previous dwells")
    if belief is not None:
        ax.plot(*belief.mean[:2], "ro", ms=9, label="source estimate")
    if plan.ok:
        ax.plot(plan.path[:, 0], plan.path[:, 1], "b-", lw=2, label="path")
        ax.plot(plan.dwell_points[:, 0], plan.dwell_points[:, 1], "gv", ms=10, label="dwell points")
        d = plan.dwell_points[0]
        ax.arrow(d[0], d[1], 0.4 * np.cos(d[3]), 0.4 * np.sin(d[3]), color="g", width=0.02)
    ax.set(xlim=(occ.bounds_min[0], occ.bounds_max[0]), ylim=(occ.bounds_min[1], occ.bounds_max[1]),
           xlabel="x (m)", ylabel="y (m)", aspect="equal", title=f"radseek plan: {plan.method}")
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.fig4 is not None:
        args.fig4.parent.mkdir(parents=True, exist_ok=True)
        plot_fig4(args.fig4)
        print(f"wrote {args.fig4}")
        return 0
    seed_ompl(args.seed + 1)  # OMPL refuses seed 0
    rng = np.random.default_rng(args.seed)
    occ, map_background = _load_map(args)
    background = map_background if args.background is None else args.background
    start = args.start
    if start is None:
        start = np.r_[occ.free_min[:2] + 0.2, occ.bounds_min[2] + 0.5 * (occ.bounds_max[2] - occ.bounds_min[2]), 0.0]
    if not occ.point_valid(*start[:3]):
        print(f"radseek plan: start {start[:3].tolist()} is inside a wall or outside the flight volume",
              file=sys.stderr)
        return 2
    dw = np.array(args.dwell).reshape(-1, 4)
    history = DwellHistory(dw[:, :3], dw[:, 3])
    belief = None
    if args.source is not None:
        belief = SourceBelief(args.source, np.eye(3) * args.sigma**2, args.cps, background)
    tree_cfg = TreeConfig(n_min=min(100, args.nodes), n_max=args.nodes)
    tree_xy = node_gain = nodes = None
    z_mid = float(start[2])

    if args.method is None:
        args.method = "next-best" if belief is not None else "explore"
        if belief is None:
            print("radseek plan: no --source belief: planning an exploration (--method explore)", file=sys.stderr)
    if args.method == "next-best":
        if belief is None:
            print("radseek plan: --method next-best needs --source (use --method explore without a belief)",
                  file=sys.stderr)
            return 2
        cfg = NextBestConfig(tree=tree_cfg)
        tree = grow_tree(start, occ, tree_cfg)
        plan = plan_next_dwell(start, belief, history, occ, cfg, rng=rng, tree=tree)
        scores = score_nodes(tree.states[:, :3], belief, history, occ, cfg)
        tree_xy, nodes = tree.edges(), tree.states
        node_gain = np.where(scores.valid, scores.gain, np.nan)
    elif args.method == "explore":
        plan = plan_exploration(start, history, occ, config=FrontierConfig(tree=tree_cfg), rng=rng)
    elif args.method == "greedy":
        if belief is None:
            print("radseek plan: --method greedy needs --source", file=sys.stderr)
            return 2
        point, _ = baselines.greedy_info_gain(start[:3], belief, occ, rng=rng)
        plan = baselines.to_plan(point[None], start, "greedy_info_gain")
    else:
        centre = np.r_[(occ.bounds_min[:2] + occ.bounds_max[:2]) / 2, z_mid] if belief is None else \
            np.r_[belief.mean[:2], z_mid]
        if args.method == "lattice":
            pts = baselines.fixed_lattice(centre, 1.0)
        elif args.method == "lawnmower":
            pts = baselines.lawnmower(occ.bounds_min, occ.bounds_max, 1.5, z_mid)
        else:
            pts = baselines.spiral(centre, 1.0, occ.free_min, occ.free_max)
        plan = baselines.to_plan(baselines.valid_points(pts, occ), start, args.method)

    if args.json:
        print(json.dumps(plan.to_topic(0.0).to_dict()))
    else:
        print(f"method {plan.method}: {len(plan.dwell_points)} dwell point(s), path {plan.path_length():.2f} m "
              f"over {len(plan.path)} waypoints")
        for k, d in enumerate(plan.dwell_points[:12]):
            g = f"  gain {plan.gains[k]:.4f}" if k < len(plan.gains) else ""
            print(f"  dwell {k}: x {d[0]:.2f}  y {d[1]:.2f}  z {d[2]:.2f}  yaw {np.degrees(d[3]):.0f} deg{g}")
        for key, value in plan.info.items():
            print(f"  {key}: {value if not isinstance(value, float) else round(value, 4)}")
    if args.plot is not None:
        _plot(args.plot, occ, plan, history, belief, tree_xy, node_gain, nodes)
        print(f"wrote {args.plot}", file=sys.stderr)
    if args.export_plan is not None and plan.ok:
        export_plan(args.export_plan, plan, occ, args.home, args.export_dwell)
        print(f"wrote {args.export_plan}", file=sys.stderr)
    return 0 if plan.ok else 1
