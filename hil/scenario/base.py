"""The base of every scenario section (hil.scenario and the studies' own sections, hil/spec_*.py)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Strict(BaseModel):
    """A scenario section: unknown keys are errors, values are frozen once loaded, and NaN or an infinity
    is a bad value for every number of a scenario."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
