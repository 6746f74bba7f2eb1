"""The framework of ``mpmref verify``: what a case declares (:mod:`~verification.framework.case`), the registry of
cases, the command line, the executor that runs their independent parts, the warm-up of compiled kernels, the
checks and findings (:mod:`~verification.framework.common`) and the reports (Markdown, HTML, VTK series and
figures)."""
