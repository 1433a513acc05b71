"""Teachers: the protocol and registry (base.py) and the built-in implementations, each
registered by name when its module is imported (:data:`~msta.policies.teacher.base.BUILTIN_TEACHERS`
names them; :func:`~msta.policies.teacher.base.make_teacher` imports a built-in on first use)."""
