"""Pieces shared by every engine: the job context, CLI progress output, data paths."""
