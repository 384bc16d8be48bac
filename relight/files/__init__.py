"""Files in and out: photos decoded to linear float32 within the size limits (PNG, JPEG, EXR), the fast
PNG writer, OpenEXR, atomic writes and hashes, clips read and written, and the scene format the farm
writes and the model reads (the only parser of scene files).
"""
