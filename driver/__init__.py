"""Thin Python driver for the FreeFEM fictitious-domain Nitsche contact package.

It validates scene files, launches FreeFEM, parses the results FreeFEM writes,
and makes tables and plots. It never recomputes what FreeFEM computes.
"""
