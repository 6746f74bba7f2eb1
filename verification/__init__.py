"""Verification cases: one module per case, each with ``Params``, ``run``, ``checks`` and ``report``."""
