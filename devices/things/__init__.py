"""The devices as WoT Things. A device kind's binding is `bind_<kind>(thing, model) -> Cleanup`
(`binding.py`): lights, platform devices, pan-tilts, fleet devices. The world, robots and virtual
Things own more than a model and are classes entered with `with`."""
