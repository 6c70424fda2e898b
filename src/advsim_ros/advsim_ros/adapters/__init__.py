"""Users' stacks: stack profiles and the conversions between a stack's own messages and the contract.

- ``profile`` the profile file (processes, inputs, outputs, timing), validated with one-line errors
- ``plans``    a stack's answer (timed or spatial poses, any frame) as the contract's plan
- ``messages`` parsers of the stacks' own plan messages, builders of the pose inputs they read
- ``timing``   which plan of a timer-driven stack answers which sweep
- ``bridge``   what the stack_adapter node relays and converts for a profile, and the contract answers it makes
"""
