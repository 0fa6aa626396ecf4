"""Plot the reachable part of the thesis's table 3-7 box (docs/reachable_set.png).

Each panel shows, for a pair (DOF, z), the fraction of the other two DOF's thesis
range (5×5 grid) that is reachable within the hard limits, for the default
interpretation (top row) and the literal one (bottom row), with the thesis box
(dashed) and the profile's restricted workspace (solid).

Run: .venv/bin/python bench/reachability_plot.py [--out docs/reachable_set.png]
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from planner.model.kinematics import HitchModel  # noqa: E402
from planner.model.workspace import Reachability  # noqa: E402
from planner.profiles.hitch import load_profile, profile_from_dict  # noqa: E402

DOFS = ("x", "z", "roll", "pitch")


def fraction_map(reach, box, a, n=25, m=5):
    others = [k for k in DOFS if k not in (a, "z")]
    av = np.linspace(*box[a], n)
    zv = np.linspace(*box["z"], n)
    ov = [np.linspace(*box[k], m) for k in others]
    out = np.zeros((n, n))
    for i, z in enumerate(zv):
        for j, v in enumerate(av):
            ok = 0
            for o1 in ov[0]:
                for o2 in ov[1]:
                    t = {a: v, "z": z, others[0]: o1, others[1]: o2}
                    ok += reach(np.array([t[k] for k in DOFS]))
            out[i, j] = ok / (m * m)
    return av, zv, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="docs/reachable_set.png")
    args = ap.parse_args()
    base = load_profile()
    d = base.model_dump()
    d["limits"]["top_link_angle_reference"] = "horizontal"
    d["workspace"]["z_reference"] = "pivot"
    rows = [
        ("default: z from the neutral height, top-link angles from the neutral direction", HitchModel(base)),
        ("literal: z from pivot height, top-link angles from the horizontal", HitchModel(profile_from_dict(d))),
    ]
    fig, axes = plt.subplots(2, 3, figsize=(13, 8.5), constrained_layout=True)
    for r, (title, model) in enumerate(rows):
        reach = Reachability(model)
        box = model.thesis_box()
        total = []
        for c, a in enumerate(("x", "roll", "pitch")):
            av, zv, frac = fraction_map(reach, box, a)
            total.append(frac.mean())
            ax = axes[r, c]
            im = ax.pcolormesh(av, zv, frac, vmin=0, vmax=1, cmap="viridis", shading="nearest")
            ax.add_patch(
                Rectangle(
                    (box[a][0], box["z"][0]),
                    box[a][1] - box[a][0],
                    box["z"][1] - box["z"][0],
                    fill=False,
                    ls="--",
                    ec="w",
                    lw=1.5,
                )
            )
            ws = base.workspace.restricted["2"].as_dict()
            if r == 0:
                ax.add_patch(
                    Rectangle(
                        (ws[a][0], ws["z"][0]), ws[a][1] - ws[a][0], ws["z"][1] - ws["z"][0], fill=False, ec="r", lw=2
                    )
                )
            ax.set_xlabel(f"{a} [{'m' if a == 'x' else 'rad'}]")
            ax.set_ylabel("z [m] (tractor frame)")
        axes[r, 0].set_title(
            f"{title}\nreachable: {100 * np.mean(total):.0f} % of the thesis box", loc="left", fontsize=10
        )
    fig.colorbar(im, ax=axes, shrink=0.6, label="fraction of the other two DOF reachable")
    fig.suptitle(
        "Thesis table 3-7 box (dashed) vs reachable set within hard limits; red: restricted workspace (cat. 2, default)"
    )
    fig.savefig(args.out, dpi=90)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
