"""The networks: RelightNet (the paper's), the geometry-first network and the differentiable physics it
derives transport, light and albedo from, and the torch twins of the core's SH operations.
"""
