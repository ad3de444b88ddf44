// Frictional contact of one ridge with a rigid plate on the condensed surface
// compliance: the event-driven path following of tactile_mirror/contact/solver.py
// (ContactSolver.follow / step), with its breakaway cascade solved by the
// primal-dual active-set (semismooth Newton) iteration and its damped-Newton fallback.
//
// The algorithm, its tolerances, the classification and the reported state are
// those of the Python reference (ContactSolver(backend="python")); see its module
// docstring ("Event-driven path following") for the equations. Here:
//
// * sizes are fixed at construction (n contact nodes, 2n unknowns) and every
//   workspace is allocated there; `follow` and `step` allocate nothing, take no lock,
//   make no system call and throw nothing: they return a ContactStatus;
// * `follow` saves the history at its start and restores it on an error, so a failed
//   call leaves the solver as it was; a pad undoes the ridges that succeeded with
//   `restore`;
// * the friction law is the rate-independent one of the reference: a node that
//   breaks away drops to the kinetic cone at the breakaway point, and the load it
//   sheds is carried at that same load (the breakaway cascade, `cascade`);
// * the pieces are separate functions (classification, the piece system and its
//   factorisation, the triangular solve, the Newton residual and Jacobian).
//
// The dense LU is partial pivoting (row-major, blocked right-looking). A pivot that
// is exactly zero is a singular system, as LAPACK getrf reports it. Factors are
// reused while the piece (classification and slip coefficients) is unchanged; a piece
// that differs from the factored one in a few nodes (the slip front moved by a node)
// is solved by bordering the factored one (a Schur complement of at most 64 rows and
// columns, its entries kept from one piece to the next; a stuck node that slides costs two borders, its slip law as a row), and a
// piece that adds touching nodes (the contact growing under the press) extends the
// base's factors by them (extend_base, O(nb m^2)), so refactorisations are rare. The
// base solves of the unit right-hand sides (the responses to a unit plate motion) are
// kept with the base, so the unit responses of a bordered piece cost O(m nb) besides
// their compliance products; so is the last base solve of a load's right-hand side,
// which the active-set steps and breakaway-cascade rounds of one load point share
// (reused when base and right-hand side are bitwise the same: the same bits as a
// fresh solve; about a tenth of a gross slip's cost). No iterative refinement: the
// bordered solves agree with the reference's fresh LAPACK factorisations as closely as
// the reference's two stepping modes agree with each other (tests/test_contact_cpp.py).
// A piece's displacements come from its own equations where they fix them
// (piece_displacement: only the open nodes and the sliding nodes' u_y take dot products
// with C). Within one piece the response is affine in the plate position; the
// active-set iteration of the breakaway cascade and the per-sample stepping (every)
// serve a piece met a third time from its reference solution and unit responses in
// O(n) (piece_response): a sample of `every` that meets no event costs no solve with
// the factors and no product with C (on fig6 stepped per sample the median step went
// from 17 to 5 us, the mean from 28 to 17 us).
//
// The code: contact_dense.hpp (the dense kernels), contact_kernel.hpp (the kernel class
// and its state), contact_piece.hpp (the piece systems), contact_path.hpp (the path
// following).
#pragma once

#include "contact_dense.hpp"
#include "contact_kernel.hpp"
#include "contact_path.hpp"
#include "contact_piece.hpp"
