"""Reading the runtime's TOML files (keys, swarm) with one-line errors naming the file."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any


def read_toml(path: Path, error: type[Exception], missing: str = "no such file") -> dict[str, Any]:
    """The document at ``path``; a missing, unreadable or invalid file raises ``error`` with
    one line naming it (``missing`` says what to do about a missing one)."""
    try:
        return tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise error(f"{path}: {missing}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read it ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc})") from None
