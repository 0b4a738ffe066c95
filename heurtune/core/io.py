"""Atomic file writing: a result file is either complete or absent."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

__all__ = ["atomic_path", "write_parquet", "check_output_file", "check_output_folder"]

# The figure formats matplotlib writes (a --plot name must end in one).
FIGURE_SUFFIXES = (".png", ".pdf", ".svg", ".eps", ".ps", ".jpg", ".jpeg", ".tif", ".tiff", ".webp")


def _blocking_file(path: Path):
    """The first existing non-folder above ``path`` (so that ``path`` cannot be created), or None."""
    for parent in path.parents:
        if parent.exists():
            return None if parent.is_dir() else parent
    return None


def check_output_file(path, option: str, suffixes=None) -> Path:
    """Check that ``path`` can be written as a file; a one-line ConfigError naming ``option``
    when it is a folder, lies under a file, or (``suffixes`` given) has another extension.

    Parameters
    ----------
    path : str or Path
    option : str
        The option that gave it, named in the error.
    suffixes : iterable of str, optional
        The allowed extensions.

    Returns
    -------
    Path
    """
    from heurtune.core.errors import ConfigError

    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{option} {path} is a folder; give a file name")
    blocking = _blocking_file(path)
    if blocking is not None:
        raise ConfigError(f"{option} {path}: {blocking} is a file, not a folder")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise ConfigError(f"{option} {path}: unknown extension {path.suffix or '(none)'!r}; "
                          f"allowed: {', '.join(suffixes)}")
    return path


def check_output_folder(path, option: str) -> Path:
    """Check that ``path`` can be a folder; a one-line ConfigError naming ``option`` when it is
    a file or lies under one.

    Parameters
    ----------
    path : str or Path
    option : str
        The option that gave it, named in the error.

    Returns
    -------
    Path
    """
    from heurtune.core.errors import ConfigError

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{option} {path} is a file; give a folder")
    blocking = _blocking_file(path)
    if blocking is not None:
        raise ConfigError(f"{option} {path}: {blocking} is a file, not a folder")
    return path


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; on success it replaces ``path`` atomically.

    Examples
    --------
    >>> with atomic_path("out.png") as tmp:          # doctest: +SKIP
    ...     fig.savefig(tmp)

    Parameters
    ----------
    path : str or Path
        The file to write.

    Yields
    ------
    Path
        The temporary path to write to.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_parquet(df, path, metadata: dict | None = None) -> None:
    """Write a DataFrame to parquet atomically; ``metadata`` (bytes to bytes) joins the file's
    schema metadata (the results folder keeps each part's fingerprint there).

    Parameters
    ----------
    df : pandas.DataFrame
    path : str or Path
    metadata : dict of bytes to bytes, optional
    """
    with atomic_path(path) as tmp:
        if metadata:
            import pyarrow as pa
            import pyarrow.parquet as pq

            table = pa.Table.from_pandas(df, preserve_index=False)
            table = table.replace_schema_metadata({**(table.schema.metadata or {}), **metadata})
            pq.write_table(table, tmp)
        else:
            df.to_parquet(tmp, index=False)
