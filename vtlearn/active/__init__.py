"""Active perception: occupancy-grid next-best-touch/view, sensor selection, active learning (thesis 5.2.3, 7.2-7.3, 8.2.3)."""
