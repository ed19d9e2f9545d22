r"""The schematic of the decision loop that the course is about (chapter 4): the filter's information
state goes to a policy, the policy picks a parameter, the filter takes its step with it, the step
costs something and leads to the next information state. A learner (chapter 6) watches the costs
and changes the policy. Drawn with matplotlib as a normal figure output (:func:`plot_decision_loop`).
"""
from __future__ import annotations

__all__ = ["plot_decision_loop"]

#: (key, x, y, text) of the boxes, in axes coordinates of a 10 x 5.2 canvas.
_BOXES = (
    ("state", 1.55, 3.6, "information state\n$\\bar{\\mathbf{s}}_k$, measurement $\\mathbf{z}_k$"),
    ("policy", 5.0, 3.6, "policy\n$\\pi(\\boldsymbol{\\theta}\\,|\\,\\bar{\\mathbf{s}}_k, \\mathbf{z}_k)$"),
    ("param", 8.45, 3.6, "parameter\n$\\boldsymbol{\\theta}_k \\in \\Theta$ (e.g. $\\kappa$)"),
    ("filter", 8.45, 1.2, "filter step\nUpdate($\\boldsymbol{\\theta}_k$), Predict"),
    ("cost", 5.0, 1.2, "one-step cost\n$\\bar L(\\bar{\\mathbf{s}}_k, \\mathbf{z}_k, \\boldsymbol{\\theta}_k)$"),
    ("next", 1.55, 1.2, "next information state\n$\\bar{\\mathbf{s}}_{k+1} = \\Phi_\\mathrm{filter}(\\dots)$"),
)


def plot_decision_loop(ax=None):
    r"""Draw the loop information state -> policy -> parameter -> filter step -> cost, with the filter
    step also producing the next information state (which closes the loop at :math:`k+1`), and a
    dashed learner that reads the costs and changes the policy. Returns the figure."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    from adaptfilt import style

    if ax is None:
        fig, ax = style.figure(size=(9.0, 4.6))
    else:
        fig = ax.figure
    ax.set_xlim(0, 10)
    ax.set_ylim(-0.5, 4.6)
    ax.set_axis_off()
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    w, h = 2.9, 1.15
    centre = {}
    for i, (key, x, y, text) in enumerate(_BOXES):
        colour = colours[0] if key in ("policy", "param") else colours[1] if key in ("filter", "state", "next") \
            else colours[3 % len(colours)]
        ax.add_patch(FancyBboxPatch((x - w / 2, y - h / 2), w, h, boxstyle="round,pad=0.05,rounding_size=0.15",
                                    facecolor=colour, alpha=0.15, edgecolor=colour, linewidth=1.5))
        ax.text(x, y, text, ha="center", va="center", fontsize=10)
        centre[key] = (x, y)

    def arrow(a, b, label="", dashed=False, rad=0.0, side=(0.0, 0.0)):
        (xa, ya), (xb, yb) = centre[a], centre[b]
        dx, dy = xb - xa, yb - ya
        # start and end at the boxes' edges
        sx = (w / 2 + 0.08) * (1 if dx > 0 else -1) if abs(dx) > 1e-9 else 0.0
        sy = (h / 2 + 0.08) * (1 if dy > 0 else -1) if abs(dy) > 1e-9 and abs(dx) < 1e-9 else 0.0
        p = FancyArrowPatch((xa + sx, ya + sy), (xb - sx, yb - sy), arrowstyle="-|>", mutation_scale=16,
                            linewidth=1.5, color="0.25", linestyle="--" if dashed else "-",
                            connectionstyle=f"arc3,rad={rad}")
        ax.add_patch(p)
        if label:
            ax.text((xa + xb) / 2 + side[0], (ya + yb) / 2 + side[1], label, ha="center", va="center",
                    fontsize=9, color="0.25")

    arrow("state", "policy", "sees", side=(0, 0.28))
    arrow("policy", "param", "picks", side=(0, 0.28))
    arrow("param", "filter", "used by", side=(0.55, 0))
    arrow("filter", "cost", "costs", side=(0, 0.28))
    y_low = 1.2 - h / 2 - 0.05
    ax.annotate("", xy=(centre["next"][0] + 0.6, y_low), xytext=(centre["filter"][0] - 0.6, y_low),
                arrowprops=dict(arrowstyle="-|>", color="0.25", lw=1.5, mutation_scale=16,
                                connectionstyle="arc3,rad=-0.12"))
    ax.text(5.0, -0.3, "the filter step also leads to", ha="center", va="center", fontsize=9, color="0.25")
    arrow("next", "state", "k -> k + 1", side=(-0.6, 0))
    ax.annotate("learner (chapter 6): reads the costs, changes the policy", xy=(5.0, 3.6 - h / 2 - 0.1),
                xytext=(5.0, 2.4), ha="center", va="center", fontsize=9, color=colours[2],
                arrowprops=dict(arrowstyle="-|>", color=colours[2], lw=1.2, linestyle="--"))
    ax.set_title("The decision loop: a policy chooses the filter's parameter at every step")
    return fig
