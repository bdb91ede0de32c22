"""`selftest`: a job that only sleeps in steps and reports progress; it checks that a worker is alive."""

from __future__ import annotations

import time
from typing import Any

from pydantic import ConfigDict, Field

from app.jobs.context import JobContext
from app.jobs.policy import OperatorRule
from app.jobs.registry import JobType, register
from app.schemas import JsonModel


class SelftestParams(JsonModel):
    model_config = ConfigDict(extra="forbid")
    steps: int = Field(default=3, ge=1, le=1000)
    step_seconds: float = Field(default=0.05, ge=0.0, le=10.0)


def run_selftest(ctx: JobContext, params: SelftestParams) -> dict[str, Any]:
    for i in range(params.steps):
        time.sleep(params.step_seconds)
        ctx.progress((i + 1) / params.steps, f"step {i + 1}/{params.steps}")
    return {"steps": params.steps, "attempt": ctx.attempt}


register(
    JobType(
        name="selftest",
        params=SelftestParams,
        handler=run_selftest,
        admin_only=False,
        description="Sleep in steps and report progress (checks that a worker runs).",
        operator_rule=OperatorRule(max_values={"steps": 500, "step_seconds": 1.0}, own_sequence=False),
        max_run_seconds=600.0,
    )
)
