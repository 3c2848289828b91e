"""The agent (RTA encoder, actor-critic, curiosity and self-supervised heads) and the policy and trainer nodes.

Arrives with the agent issue; the package exists now so that the layout, packaging and entry points are fixed.
"""
