"""The files the package reads and writes outside a run's CSVs.

yaml_files.py   every YAML file it reads (params files, study plans, a run's settings), read one way
paths.py        where the installed package keeps its params and launch files
mcap_record.py  a run's record as one MCAP file, written and read back without ROS
"""
