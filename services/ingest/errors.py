"""Errors raised on bad input files (all are ``ValueError`` with a readable text)."""


class ClipError(ValueError):
    """A motion file that cannot be turned into a clip."""


class BvhError(ClipError):
    """Malformed BVH text (the message names the file and line)."""


class C3dError(ClipError):
    """Unreadable C3D file or missing markers."""


class SkeletonMapError(ClipError):
    """A rig that no skeleton map fits, or a malformed map file."""
