"""Generic utility blocks (pythonfmu FMUs) the scenarios and the SSP export need."""

from harness.blocks.build import BLOCK_KINDS, block_fmu, default_cache_dir

__all__ = ["BLOCK_KINDS", "block_fmu", "default_cache_dir"]
