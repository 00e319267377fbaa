"""Does asynchrony change the result? Each method's lockstep seeds against its asynchronous
ones: `python -m studies.schedule_effect` writes docs/results/asynchrony.md.
"""
