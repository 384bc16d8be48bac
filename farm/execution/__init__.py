"""Running many scenes: what a run is and how it fails, the local executor and its worker pool, the Ray
executor, the output folder (resume, validation, free space), the run log, the progress line, and
the dataset summary.
"""
