"""The person in a real photo: the person matte (which pixels are the person, softly, at full
resolution), operations on masks, the one box type, and the one check of a photo as the core takes
it.
"""
