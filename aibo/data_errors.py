"""A learner's errors about its data, which knows no file names, as one line naming the file and the field."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from aibo.errors import CLIError
from learners.em.support import InsufficientDataError, StartModelError


@contextmanager
def naming_files(logs: Sequence[str], init: str | None = None) -> Iterator[None]:
    """Re-raise the learner's InsufficientDataError / StartModelError as a CLIError naming the log file(s)
    (and ``init``, the start model file) and the field, as every other input error does:
    ``LOG.npz: field 'sighting_frame': the logs hold 0 sightings; ...``."""
    try:
        yield
    except InsufficientDataError as exc:
        raise CLIError(f"{', '.join(str(p) for p in logs)}: field '{exc.field}': {exc}") from exc
    except StartModelError as exc:
        where = f"{init}: field '{exc.model_field}': " if init else ""
        log = f"{logs[0]}: field '{exc.field}'" if exc.field else f"{logs[0]}"
        raise CLIError(f"{where}{exc} ({log})") from exc
