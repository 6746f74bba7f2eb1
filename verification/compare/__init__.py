"""``mpmref compare SCENE.toml FRAMES``: judge a whole run of any MPM code, from the frames it wrote, against an
ensemble of mpmref's own runs of the scene perturbed at round-off (docs/comparing_runs.md).

:mod:`.ensemble` runs the members, :mod:`.statistics` says what each frame is worth, :mod:`.verdict` judges each
frame, :mod:`.comparison` puts them together and :mod:`.report` writes ``results.json``, ``index.html``, the figures
and the VTK file of where the code's particles part from the control's.
"""

from .comparison import DEFAULT_MEMBERS, Comparison, compare

__all__ = ["DEFAULT_MEMBERS", "Comparison", "compare"]
