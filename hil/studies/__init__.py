"""The study registry: every study railhil has, in the order their hooks are called.

A study is a folder of this package with the same files in each (hil.scenario.registry lists them and
says what each holds).  Adding one: copy a study's folder, give it a section name and a descriptor in
its __init__.py, and list it here.  The foundation never imports a study; it reads this registry.
"""

from hil.studies import anticollision, consensus, decel_feedback, precise_stop, preview_slip, wheel_slip

#: in hook order: the node-replacing studies first, then the functions that add to the BCU in the order
#: their frames enter its binding (feedback sensors, ACD requests, stop target)
STUDIES = (
    preview_slip.STUDY,
    wheel_slip.STUDY,
    decel_feedback.STUDY,
    consensus.STUDY,
    anticollision.STUDY,
    precise_stop.STUDY,
)
