"""Print the service's OpenAPI document.

Regenerate the committed file with
``python -m neural_shdf.api.openapi > openapi/openapi.json``.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from neural_shdf.api.app import create_app
from neural_shdf.api.settings import Settings


def openapi_document() -> dict[str, Any]:
    """The OpenAPI schema of an app built with default settings (independent of the env)."""
    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(Settings(_env_file=None, cache_dir=Path(tmp), redis_url=None))
        return app.openapi()


def render() -> str:
    return json.dumps(openapi_document(), indent=2, sort_keys=True) + "\n"


if __name__ == "__main__":
    sys.stdout.write(render())
