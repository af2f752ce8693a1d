"""Active perception (thesis 5.2.3, 7.2-7.3, 8.2.3).

Occupancy-grid next-best-touch/view, joint sensor selection, and MC-dropout active learning.
"""
