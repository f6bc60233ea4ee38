"""Job status."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path

from neural_shdf.api.routes.deps import EngineDep, error_responses
from neural_shdf.api.schemas import JOB_ID_EXAMPLE, JOB_ID_PATTERN, Job

router = APIRouter(prefix="/v1", tags=["jobs"])


@router.get(
    "/jobs/{job_id}",
    operation_id="get_job",
    summary="Job state and progress",
    response_model=Job,
    responses=error_responses(404),
)
async def get_job(
    engine: EngineDep,
    job_id: Annotated[
        str, Path(pattern=JOB_ID_PATTERN, description="Job id.", examples=[JOB_ID_EXAMPLE])
    ],
) -> Job:
    """Poll until `succeeded` (then fetch `result_url`) or `failed` (see `error`).

    A job whose worker stopped (crash, restart) is run again by the worker answering
    the poll (`attempt` counts the runs); after a few runs it fails with `worker_lost`.
    """
    return Job(**await engine.job(job_id))
