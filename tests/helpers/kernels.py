"""The Dr.Jit kernels a call launches (the kernel-count tests' one helper)."""


def launched_kernels(fn, min_ops: int = 0) -> list[dict]:
    """Dr.Jit's history entries of the kernels of at least ``min_ops`` operations that
    ``fn()`` launched, in launch order (``hash``, ``operation_count``, ``size``, ...)."""
    import drjit as dr

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()  # clears the history
        fn()
        return [e for e in dr.kernel_history()
                if "hash" in e and e.get("operation_count", 0) >= min_ops]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
