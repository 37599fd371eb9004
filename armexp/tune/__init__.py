"""Gain tuning: cuckoo search (Algorithm 2) and the controller objective (DESIGN §5)."""

from armexp.tune.cuckoo import CuckooResult, cuckoo_search

__all__ = ["CuckooResult", "cuckoo_search"]
