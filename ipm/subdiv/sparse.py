"""A fixed sparse matrix applied to a dense tensor, differentiable with respect to the dense one:
forward ``S @ X``, backward ``S^T @ G`` (the matrix itself carries no gradient)."""

from __future__ import annotations

import warnings

import numpy as np
import scipy.sparse as sp
import torch


def to_torch(S: sp.spmatrix, dtype: torch.dtype = torch.float64, device: torch.device | str = "cpu"
             ) -> torch.Tensor:
    """A scipy sparse matrix as a torch CSR tensor (its invariants checked once, here)."""
    S = sp.csr_matrix(S)
    S.sum_duplicates()  # sorted, distinct column indices per row: what torch's CSR checks
    # made outside any torch.func transform (jacfwd's tracing wrappers cannot hold a sparse tensor): the
    # matrix is a constant of the function being differentiated
    with warnings.catch_warnings(), torch._C._DisableFuncTorch():
        warnings.simplefilter("ignore", UserWarning)  # "sparse CSR support is in beta": only S @ X is used
        return torch.sparse_csr_tensor(torch.as_tensor(S.indptr, dtype=torch.int64),
                                       torch.as_tensor(S.indices, dtype=torch.int64),
                                       torch.as_tensor(np.asarray(S.data), dtype=dtype), size=S.shape,
                                       device=device, check_invariants=True)


class _Pair:
    """``S`` and its transpose as one non-tensor argument: torch.func lifts every tensor argument of an
    autograd.Function into its wrappers, which a sparse tensor cannot enter."""

    def __init__(self, S: torch.Tensor, St: torch.Tensor):
        self.S, self.St = S, St

    def transposed(self) -> _Pair:
        """The pair for ``S^T``: what the backward pass applies."""
        return _Pair(self.St, self.S)


class _SparseApply(torch.autograd.Function):
    """``S @ X`` for a fixed sparse ``S``: backward ``S^T @ G``, forward mode ``S @ dX``, and a batching
    rule, so torch.func's jacfwd, jacrev and vmap work through it."""

    @staticmethod
    def forward(pair: _Pair, X: torch.Tensor) -> torch.Tensor:
        """``S @ X`` (the pair carries no gradient)."""
        return pair.S @ X

    @staticmethod
    def setup_context(ctx, inputs, output):
        """Keeps the pair for the backward and forward-mode passes."""
        ctx.pair = inputs[0]

    @staticmethod
    def backward(ctx, g: torch.Tensor):
        """``S^T @ g`` for ``X``, nothing for the pair."""
        return None, _SparseApply.apply(ctx.pair.transposed(), g)

    @staticmethod
    def jvp(ctx, _dpair, dX: torch.Tensor) -> torch.Tensor:
        """Forward mode: ``S @ dX``."""
        return _SparseApply.apply(ctx.pair, dX)

    @staticmethod
    def vmap(info, in_dims, pair: _Pair, X: torch.Tensor):
        """Batching rule: the batch dimension of ``X`` becomes trailing columns, so a vmap is one sparse product."""
        d = in_dims[1]
        if d is None:
            return _SparseApply.apply(pair, X), None
        Xb = X.movedim(d, -1)                       # the batch as trailing columns: one sparse product
        out = _SparseApply.apply(pair, Xb.reshape(Xb.shape[0], -1))
        return out.reshape(pair.S.shape[0], *Xb.shape[1:]), Xb.ndim - 1


class SparseOperator:
    """``S (N, n)`` held as torch CSR tensors (and its transpose) of one dtype and device; calling it on
    ``X (n, k)`` gives ``S @ X`` with gradient ``S^T @ G``. The tensors follow the first input's dtype
    and device (converted once and kept)."""

    def __init__(self, S: sp.spmatrix):
        self.scipy = sp.csr_matrix(S)
        self.shape = self.scipy.shape
        self._cache: dict[tuple, tuple[torch.Tensor, torch.Tensor]] = {}

    def tensors(self, dtype: torch.dtype, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
        """``(S, S^T)`` as torch CSR tensors of this dtype and device (converted on first use, then cached)."""
        key = (dtype, str(device))
        if key not in self._cache:
            self._cache[key] = (to_torch(self.scipy, dtype, device), to_torch(self.scipy.T, dtype, device))
        return self._cache[key]

    def __call__(self, X: torch.Tensor) -> torch.Tensor:
        if X.shape[0] != self.shape[1]:
            raise ValueError(f"sparse operator of shape {self.shape} applied to {tuple(X.shape)}")
        return _SparseApply.apply(_Pair(*self.tensors(X.dtype, X.device)), X)
