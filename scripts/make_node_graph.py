"""Draw the node graph of the vehicle set: nodes, the topics between them, who reads them.

Writes ``docs/img/node_graph.svg`` (or ``--out FILE``; the format follows the suffix: svg, png,
pdf) with Graphviz ``dot`` when it is on PATH (``apt-get install graphviz``), else with
matplotlib. ``--dot FILE`` also writes the Graphviz source.

Usage::

    python scripts/make_node_graph.py [--out docs/img/node_graph.svg] [--dot FILE]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# (name, label, kind, cluster): kind "node" is a ROS node, "topic" a topic, "ext" outside the set.
ITEMS = [
    ("bridge", "serial bridge\n(ATmega328P firmware,\nor the emulator on a pty)", "ext", ""),
    ("esc_driver", "esc_driver\n(lifecycle)", "node", "container"),
    ("nominal_model", "nominal_model\n(NARX)", "node", "container"),
    ("classifier", "classifier", "node", "container"),
    ("health", "health", "node", "container"),
    ("recorder", "recorder\n(writer thread)", "node", "container"),
    ("mission", "mission software /\nthrust allocator\n(or command_player)", "ext", ""),
    ("telemetry", "esc/telemetry", "topic", ""),
    ("command", "esc/command", "topic", ""),
    ("residual", "fdd/residual", "topic", ""),
    ("diagnosis", "fdd/diagnosis", "topic", ""),
    ("health_topic", "/thruster_fdd/health", "topic", ""),
    ("diagnostics", "/diagnostics", "topic", ""),
    ("bag", "rosbag2 bag\n(MCAP files)", "ext", ""),
]
EDGES = [
    ("bridge", "esc_driver", "serial"),
    ("esc_driver", "telemetry", ""),
    ("telemetry", "nominal_model", ""),
    ("nominal_model", "residual", ""),
    ("residual", "classifier", ""),
    ("classifier", "diagnosis", ""),
    ("diagnosis", "health", ""),
    ("residual", "health", ""),
    ("health", "health_topic", ""),
    ("health_topic", "mission", ""),
    ("diagnostics", "mission", ""),
    ("mission", "command", ""),
    ("command", "esc_driver", ""),
    ("recorder", "bag", ""),
]
STYLE = {
    "node": 'shape=box style="rounded,filled" fillcolor="#dbe9f6" color="#3a6ea5"',
    "topic": 'shape=note style=filled fillcolor="#fdf1d6" color="#b08a2e" fontname="monospace"',
    "ext": 'shape=box style="dashed" color="#777777" fontcolor="#444444"',
}


def dot_source() -> str:
    """The graph in Graphviz's language."""
    lines = [
        "digraph thruster_fdd {",
        '  rankdir=LR; nodesep=0.3; ranksep=0.45; fontname="Helvetica";',
        '  node [fontname="Helvetica" fontsize=11]; edge [color="#555555" arrowsize=0.7];',
        '  labelloc=t; label="thruster_fdd on the vehicle: per thruster /thruster/<id>/...";',
        "  subgraph cluster_container {",
        "    label=\"container (one process: every thruster's three nodes, health and recorder;\\n"
        "telemetry -> residual -> diagnosis -> health and every message -> recorder by direct "
        'calls)";',
        '    style="rounded"; color="#3a6ea5"; fontsize=10;',
    ]
    for name, label, kind, cluster in ITEMS:
        if cluster == "container":
            lines.append(f'    {name} [label="{_esc(label)}" {STYLE[kind]}];')
    lines.append("  }")
    for name, label, kind, cluster in ITEMS:
        if cluster != "container":
            lines.append(f'  {name} [label="{_esc(label)}" {STYLE[kind]}];')
    for a, b, label in EDGES:
        attrs = f' [label="{label}" dir=both fontname="Helvetica" fontsize=9]' if label else ""
        lines.append(f"  {a} -> {b}{attrs};")
    lines += [
        '  every [label="every topic" shape=plaintext fontcolor="#777777"];',
        "  every -> recorder [style=dashed];",
        '  nodes [label="every node" shape=plaintext fontcolor="#777777"];',
        "  nodes -> diagnostics [style=dashed];",
        "}",
    ]
    return "\n".join(lines) + "\n"


def _esc(label: str) -> str:
    return label.replace('"', '\\"').replace("\n", "\\n")


def draw_matplotlib(out: Path) -> None:
    """A plain drawing of the same graph, for machines without Graphviz."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    where = {
        "bridge": (0, 2), "esc_driver": (2, 2), "telemetry": (3.5, 2.8),
        "nominal_model": (5, 2), "residual": (6.5, 2.8), "classifier": (8, 2),
        "diagnosis": (9.5, 2.8), "health": (11, 2), "health_topic": (12.5, 2.8),
        "mission": (14, 2), "command": (8, 0.4), "diagnostics": (12.5, 0.4),
        "recorder": (2, 0.4), "bag": (3.8, 0.4),
    }  # fmt: skip
    colours = {"node": "#dbe9f6", "topic": "#fdf1d6", "ext": "white"}
    fig, ax = plt.subplots(figsize=(15, 4))
    for a, b, _ in EDGES:
        (x0, y0), (x1, y1) = where[a], where[b]
        ax.annotate("", (x1, y1), (x0, y0), arrowprops={"arrowstyle": "->", "color": "#555"})
    for name, label, kind, _ in ITEMS:
        x, y = where[name]
        ax.text(x, y, label, ha="center", va="center", fontsize=8,
                bbox={"boxstyle": "round", "fc": colours[kind], "ec": "#3a6ea5"})  # fmt: skip
    ax.set_xlim(-1, 15)
    ax.set_ylim(-0.5, 3.5)
    ax.axis("off")
    fig.savefig(out, bbox_inches="tight")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=REPO / "docs" / "img" / "node_graph.svg")
    p.add_argument("--dot", type=Path, help="also write the Graphviz source here")
    args = p.parse_args(argv)
    source = dot_source()
    if args.dot:
        args.dot.write_text(source)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if shutil.which("dot"):
        fmt = args.out.suffix.lstrip(".") or "svg"
        subprocess.run(["dot", f"-T{fmt}", "-o", str(args.out)], input=source, text=True,
                       check=True)  # fmt: skip
    else:
        draw_matplotlib(args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
