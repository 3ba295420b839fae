//! Colour: CIE 1931 tables, spectrum -> XYZ -> CIELAB, colour differences, sRGB.
