"""The literature brdftab implements, keyed like ``Walter2007``.

Models, components, grids and checks cite these keys in their ``reference`` attribute (keys
separated by ``;``) and in docstrings (``[Walter2007]``); :func:`cite` expands them for
``brdftab models NAME`` and table provenance. A test checks every cited key exists.
"""

from __future__ import annotations

import re

__all__ = ["REFERENCES", "cite", "keys_in"]

REFERENCES = {
    "Aspnes1983": "D. E. Aspnes, A. A. Studna, \"Dielectric functions and optical parameters of Si, Ge, GaP, GaAs, "
                  "GaSb, InP, InAs, and InSb from 1.5 to 6.0 eV\", Phys. Rev. B 27, 985 (1983).",
    "Beckmann1963": "P. Beckmann, A. Spizzichino, The Scattering of Electromagnetic Waves from Rough Surfaces, "
                    "Pergamon (1963).",
    "Bitterling2024": "M. Bitterling et al., \"Physical models of the bidirectional reflectance of solar receiver "
                      "coatings\" (Pyromark 2500), Solar Energy.",
    "Blinn1977": "J. F. Blinn, \"Models of light reflection for computer synthesized pictures\", SIGGRAPH (1977).",
    "Butler2015": "S. D. Butler, S. E. Nauyoks, M. A. Marciniak, \"Comparison of microfacet BRDF model to modified "
                  "Beckmann-Kirchhoff BRDF model for rough and smooth surfaces\", Opt. Express 23, 29100 (2015).",
    "BornWolf1999": "M. Born, E. Wolf, Principles of Optics, 7th ed., Cambridge (1999), §1.5.2 and §14.2.",
    "Cook1982": "R. L. Cook, K. E. Torrance, \"A reflectance model for computer graphics\", ACM TOG 1, 7 (1982).",
    "DeHaas2024": "L. de Haas, \"Pyramidal microfacets: fitting a microfacet model to a pyramid-textured solar cell\", "
                  "MSc thesis, TU Delft (2024).",
    "DupuyJakob2018": "J. Dupuy, W. Jakob, \"An adaptive parameterization for efficient material acquisition and "
                      "rendering\", ACM TOG 37(6) (2018).",
    "Germer2017": "T. A. Germer, \"Full four-dimensional and reciprocal Mueller matrix bidirectional reflectance "
                  "distribution function of sintered polytetrafluoroethylene\", Appl. Opt. 56, 9333 (2017).",
    "He1991": "X. D. He, K. E. Torrance, F. X. Sillion, D. P. Greenberg, \"A comprehensive physical model for light "
              "reflection\", SIGGRAPH (1991).",
    "Goodman2005": "J. W. Goodman, Introduction to Fourier Optics, 3rd ed., Roberts (2005), §4.4 (Fraunhofer "
                   "diffraction by rectangular apertures).",
    "Heitz2016": "E. Heitz, J. Hanika, E. d'Eon, C. Dachsbacher, \"Multiple-scattering microfacet BSDFs with the "
                 "Smith model\", ACM TOG 35(4) (2016).",
    "Heitz2014": "E. Heitz, \"Understanding the masking-shadowing function in microfacet-based BRDFs\", JCGT 3(2) "
                 "(2014).",
    "Koenderink1998": "J. J. Koenderink, A. J. van Doorn, \"Phenomenological description of bidirectional surface "
                      "reflection\", JOSA A 15, 2903 (1998).",
    "Lambert1760": "J. H. Lambert, Photometria (1760).",
    "Matusik2003": "W. Matusik, H. Pfister, M. Brand, L. McMillan, \"A data-driven reflectance model\", SIGGRAPH "
                   "(2003); MERL BRDF database BRDFRead.cpp.",
    "Nicodemus1977": "F. E. Nicodemus et al., Geometrical Considerations and Nomenclature for Reflectance, NBS "
                     "Monograph 160 (1977).",
    "Rusinkiewicz1998": "S. M. Rusinkiewicz, \"A new change of variables for efficient BRDF representation\", "
                        "Eurographics Workshop on Rendering (1998).",
    "SCATMECH2021": "T. A. Germer, SCATMECH: Polarized Light Scattering C++ Class Library, NIST, version 7.22 "
                    "(2021), ZernikeExpansion_BRDF_Model (code/zernikeexpansion.cpp, docs/zernikeexpansion.htm), "
                    "https://github.com/usnistgov/SCATMECH.",
    "Schlick1994": "C. Schlick, \"An inexpensive BRDF model for physically-based rendering\", CGF 13(3) (1994).",
    "Small2021": "T. V. Small, S. D. Butler, M. A. Marciniak, \"Solar cell BRDF measurement and modeling with "
                 "out-of-plane data\", Opt. Express 29, 35501 (2021).",
    "Smith1967": "B. G. Smith, \"Geometrical shadowing of a random rough surface\", IEEE TAP 15, 668 (1967).",
    "Stover2012": "J. C. Stover, Optical Scattering: Measurement and Analysis, 3rd ed., SPIE (2012), §5 "
                  "(Rayleigh-Rice vector perturbation theory).",
    "Torrance1967": "K. E. Torrance, E. M. Sparrow, \"Theory for off-specular reflection from roughened surfaces\", "
                    "JOSA 57, 1105 (1967).",
    "Trowbridge1975": "T. S. Trowbridge, K. P. Reitz, \"Average irregularity representation of a rough surface for "
                      "ray reflection\", JOSA 65, 531 (1975).",
    "Walter2007": "B. Walter, S. R. Marschner, H. Li, K. E. Torrance, \"Microfacet models for refraction through "
                  "rough surfaces\", EGSR (2007).",
}

_KEY = re.compile(r"^[A-Z][A-Za-z]+[0-9]{4}[a-z]?$")


def keys_in(reference: str) -> list:
    """The citation keys of a ``reference`` attribute (``"Walter2007; Heitz2014"``)."""
    return [k.strip() for k in (reference or "").split(";") if k.strip()]


def cite(reference: str) -> list:
    """Full citations for the keys of a ``reference`` attribute (unknown keys raise KeyError)."""
    return [REFERENCES[k] for k in keys_in(reference)]
