"""Slip control with preview: slip references Lf (leader-follower), Bd (blind decentralised) and Dp
(distributed preview) for the cars of a train, and the slip controller that tracks them.

Paper: seed 000, M. Picasso, D. Caporale, P. Colaneri, "A distributed braking control algorithm with
preview action for railroad vehicles" (../shared/seeds/000_906f395ef368f1df.txt).  Controllers:
firmware_py/preview.py, firmware_py/slipctl.py; the paper's reduced model: plant_sim/reduced_train.py.
Docs: docs/studies/preview-slip.md.
"""

from hil.scenario.registry import Study
from hil.studies.preview_slip.scenario import PreviewSpec

STUDY = Study(
    name="preview_slip", section="preview", spec=PreviewSpec, package=__name__,
    title="slip references Lf/Bd/Dp with preview: Table 1 and campaigns 2-3, full mode on the wheelset plant",
    paper="seed 000: Picasso, Caporale, Colaneri, distributed braking control with preview action",
)
