"""Gain tuning: cuckoo search (Algorithm 2) and the controller objective (docs/design.md §5)."""

from armexp.tune.cuckoo import CuckooResult, cuckoo_search

__all__ = ["CuckooResult", "cuckoo_search"]
