// The physics terms of a pass (deformgl/sim/terms): the host composes this file for a system that
// holds terms (deformgl/sim/terms/glsl.py PassTerms.chunks: each term's chunk, then terms_force,
// and with TERMS_IMPLICIT terms_product and terms_diagonal calling each term's function in turn).
// This shipped file is the empty list: the shared passes include it only under #ifdef TERMS, which
// the host defines only with terms.
