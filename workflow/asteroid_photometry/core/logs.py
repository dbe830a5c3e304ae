"""Logging set-up shared by the rule scripts: everything goes to the rule's ``log:`` file."""

import logging
import sys


def setup_logging(log_path=None, level=logging.INFO):
    """Send this process's log records to ``log_path`` (or stderr) and return the root logger."""
    handler = logging.FileHandler(log_path, mode="w") if log_path else logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)
    return root
