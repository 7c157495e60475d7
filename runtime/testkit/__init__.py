"""The test kit for plugin authors (``rdsl test-plugin``) and the stdlib's tests: the
chi-square machinery (:mod:`.chi2`), one plugin called as the renderer calls it
(:mod:`.harness`), the checks of a BSDF, an emitter and a texture (:mod:`.bsdf_checks`,
:mod:`.emitter_checks`, :mod:`.texture_checks`), their table (:mod:`.report`) and the
command (:mod:`.cli`)."""
