"""The parameters of the range screening (`links.screen`), shared by every detector's
parameters (kept apart from `links` so that `noise` can use them without importing the solver)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field


class LinkParams(BaseModel):
    """Range screening shared by every detector (`links.screen`)."""

    links: Literal["screen", "off"] = Field(
        "screen", description="drop links whose ranges read long (NLOS) and flag enlarged drones first"
    )
    link_k: float = Field(5.0, gt=0, description="a link reads long beyond this many sigmas")
    link_nlos_max: float = Field(
        2.0, gt=0, description="two ways disagreeing by more than this (m) are tampering, not NLOS"
    )
    link_rounds: int = Field(20, ge=1, le=100, description="robust shape fits of the screening at most")
