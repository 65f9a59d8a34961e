"""Host classes of the WGSL kernels, one module per ``shaders/<group>/``: kernel K
(``shaders/<group>/K.wgsl``) is the class ``CamelCase(K)`` in ``kernels/<group>.py``."""
