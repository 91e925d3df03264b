"""Models: one file per model; the shared interface is in :mod:`.base`.

A model is found by its config's ``_target_`` (``conf/model/<name>.yaml``).
"""
