"""What the runs' CSVs say: statistics and figures.

stats.py        IQM, bootstrap intervals, paired tests, TOST (the study's statistics)
plots.py        figures from a learner's episodes.csv
"""
