"""Moved to :mod:`ipm.files` (kept for callers not yet updated)."""

from ipm.files import all_or_nothing, atomic_path, check_writable, staged_directory, write_bytes, write_text

__all__ = ["all_or_nothing", "atomic_path", "check_writable", "staged_directory", "write_bytes", "write_text"]
