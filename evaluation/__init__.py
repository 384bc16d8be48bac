"""evaluation: measuring tools that are not part of the shipped core (torch-free, bpy-free).

`evaluation.sheet` tiles images into contact sheets (model/evaluate*.py, tools/demo.py);
`evaluation.matte_eval` scores person mattes against the reference mattes of
evaluation/data/matte_eval (`python -m evaluation.matte_eval`). They use `relight/`;
the Blender add-on does not bundle them.
"""
