"""The farm: one plan of a sequence's shots (``plan``), run by the schedulers studios already have.

``shots`` reads the shots file, ``plan`` turns it into tasks with their exact engine command lines and
dependencies, and each back end (``openjd``, ``dask_backend``, ``flamenco``) submits those very command lines.
"""
