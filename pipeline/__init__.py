"""Pipeline: robot and localisation, reader acquisition, evaluation, figures and orchestration."""

__all__ = []
