"""Errors a user can cause and fix; the CLI prints them as one line and exits non-zero."""


class UserError(Exception):
    """Bad input (arguments, files, directories): message is shown as-is, no traceback."""
