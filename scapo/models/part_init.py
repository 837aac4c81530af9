"""Data-driven initial part split for stage 2: choose the split that moves most rigidly.

Stage 2 (paper Sec. 3.2-3.3) must discover the parts from unlabeled clouds. Its regularisers
``L_kp-seg`` (keypoints at their parts' centroids) and ``L_seg`` (each point with its nearest
keypoint) together act like k-means on the canonical shape, and k-means splits an object along
its largest extent: a laptop is cut into left and right halves (through the hinge axis) rather
than into base and screen, a local minimum that the cross-space term does not leave in a short
CPU training. This module picks the starting split with the property that defines a part: across
instances, each part moves rigidly.

For a candidate set of keypoints ``K (P, 3)`` in the canonical frame, every canonical training
cloud is segmented by nearest keypoint; for random pairs of clouds (different instances and
articulation states) each part of one cloud is registered rigidly to the same part of the other
(point-to-point ICP with Kabsch steps); the candidate's score is the mean clipped squared
residual. A split through a moving joint leaves residuals where the articulation differs; the
true parts do not. Candidates are two-way plane splits over a hemisphere of directions (P = 2)
and k-means solutions from many random starts (any P). This is an addition to the paper (its
keypoint head starts from a fixed initialisation); it uses only the unlabeled points.

Units: the model's normalised canonical units. Shapes: ``S (B, n, 3)`` canonical clouds.
"""

from __future__ import annotations

import math

import torch

from scapo.ops.align import kabsch
from scapo.ops.chamfer import pairwise_sq_dist, trimmed_one_sided_chamfer

EPS = 1e-9


def register_parts(A: torch.Tensor, B: torch.Tensor, la: torch.Tensor, lb: torch.Tensor, num_parts: int,
                   iters: int = 8, clip: float = 0.01) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Register each part of ``A`` rigidly onto the same part of ``B`` (point-to-point ICP).

    ``A, B (Q, n, 3)`` clouds, ``la, lb (Q, n)`` int64 part labels in ``[0, num_parts)``. For every
    part, ``iters`` nearest-neighbour + Kabsch steps from the identity move ``A``'s points of the
    part onto ``B``'s points of the part (matches farther than ``2 sqrt(clip)`` are ignored).

    Returns ``(residual (Q,), R (Q, P, 3, 3), t (Q, P, 3))``: the residual is the mean over ``A``'s
    points of ``min(d^2, clip)`` after registration (``clip`` in squared normalised units; a part
    absent from ``B`` leaves its points at ``clip``); ``R, t`` map part ``p`` of ``A`` onto ``B``.
    """
    Q, n, _ = A.shape
    P = num_parts
    Ap = A.unsqueeze(1).expand(Q, P, n, 3).reshape(Q * P, n, 3)
    Bp = B.unsqueeze(1).expand(Q, P, n, 3).reshape(Q * P, n, 3)
    parts = torch.arange(P, device=A.device)
    ma = (la.unsqueeze(1) == parts[None, :, None]).reshape(Q * P, n)
    mb = (lb.unsqueeze(1) == parts[None, :, None]).reshape(Q * P, n)
    big = torch.tensor(1e6, dtype=A.dtype, device=A.device)
    R = torch.eye(3, dtype=A.dtype, device=A.device).expand(Q * P, 3, 3)
    t = torch.zeros(Q * P, 3, dtype=A.dtype, device=A.device)
    cur = Ap
    other = ~mb.unsqueeze(1)  # (QP, 1, n): B's points of the other parts
    for it in range(iters + 1):
        d2 = pairwise_sq_dist(cur, Bp).masked_fill_(other, big)  # (QP, n, n), filled in place
        dmin, j = d2.min(-1)
        if it == iters:
            break
        w = (ma & (dmin < 4 * clip)).to(A.dtype)
        R, t = kabsch(Ap, Bp.gather(1, j.unsqueeze(-1).expand(-1, -1, 3)), w)
        cur = Ap @ R.transpose(1, 2) + t[:, None]
    per_point = dmin.clamp(max=clip) * ma.to(A.dtype)  # (QP, n)
    return per_point.reshape(Q, P, n).sum((1, 2)) / n, R.reshape(Q, P, 3, 3), t.reshape(Q, P, 3)


def part_rigidity_residual(A: torch.Tensor, B: torch.Tensor, la: torch.Tensor, lb: torch.Tensor, num_parts: int,
                           iters: int = 8, clip: float = 0.01) -> torch.Tensor:
    """The residual ``(Q,)`` of :func:`register_parts` (mean clipped squared distance after registering
    each part of ``A`` rigidly onto the same part of ``B``)."""
    return register_parts(A, B, la, lb, num_parts, iters, clip)[0]


def axis_from_motions(R: torch.Tensor, t: torch.Tensor, joint_type: int, min_angle_deg: float = 10.0
                      ) -> torch.Tensor | None:
    """Joint axis ``(3,)`` from relative child-to-parent motions ``x -> R x + t`` (``R (Q, 3, 3)``,
    ``t (Q, 3)``) observed between pairs of clouds in one (canonical) frame.

    Revolute (``joint_type`` 0): the principal direction of the motions' rotation axes, weighted by
    angle (motions under ``min_angle_deg`` are ignored). Prismatic (1): the principal direction of
    the translations. ``None`` when fewer than three motions are usable. (The pivots that ICP gives
    drift where flat parts slide on each other, so pivots are taken from the part boundary.)
    """
    if joint_type == 1:
        return torch.linalg.eigh(t.T @ t).eigenvectors[:, -1] if len(t) >= 3 else None
    cos = ((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0).clamp(-1.0, 1.0)
    angle = torch.arccos(cos)
    use = angle > math.radians(min_angle_deg)
    if int(use.sum()) < 3:
        return None
    R, angle = R[use], angle[use]
    u = torch.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], -1)
    u = u / (u.norm(dim=-1, keepdim=True) + EPS)
    return torch.linalg.eigh(torch.einsum("q,qi,qj->ij", angle, u, u)).eigenvectors[:, -1]


def random_pairs(count: int, pairs: int, generator: torch.Generator | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """``pairs`` random ordered pairs ``(a, b)`` of different indices in ``[0, count)``: two ``(pairs,)``
    int64 tensors. Needs ``count >= 2``."""
    a = torch.randint(count, (pairs,), generator=generator)
    return a, (a + 1 + torch.randint(count - 1, (pairs,), generator=generator)) % count


def nearest_keypoint(points: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Part labels by nearest keypoint: ``points (B, n, 3)``, ``K (B, P, 3)`` -> int64 ``(B, n)``; or
    unbatched ``(n, 3)``, ``(P, 3)`` -> ``(n,)``."""
    if points.dim() == 2:
        return pairwise_sq_dist(points[None], K[None])[0].argmin(-1)
    return pairwise_sq_dist(points, K).argmin(-1)


def fibonacci_hemisphere(count: int, dtype=torch.float32) -> torch.Tensor:
    """``count`` nearly uniform unit directions ``(count, 3)`` with ``z >= 0`` (a half Fibonacci sphere)."""
    i = torch.arange(count, dtype=torch.float64) + 0.5
    z = 1.0 - i / count  # (0, 1]
    r = (1.0 - z ** 2).clamp_min(0).sqrt()
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1).to(dtype)


def kmeans(points: torch.Tensor, k: int, starts: int, iters: int = 20, generator: torch.Generator | None = None
           ) -> torch.Tensor:
    """Lloyd's k-means from ``starts`` k-means++ seedings: ``points (M, 3)`` -> centres ``(starts, k, 3)``."""
    M = points.shape[0]
    C = torch.empty(starts, k, 3, dtype=points.dtype, device=points.device)
    first = torch.randint(M, (starts,), generator=generator)
    C[:, 0] = points[first]
    for c in range(1, k):
        d = pairwise_sq_dist(points.unsqueeze(0).expand(starts, M, 3), C[:, :c]).min(-1).values  # (starts, M)
        pick = torch.multinomial(d.cpu() + EPS, 1, generator=generator).squeeze(1).to(points.device)
        C[:, c] = points[pick]
    X = points.unsqueeze(0).expand(starts, M, 3)
    for _ in range(iters):
        lab = pairwise_sq_dist(X, C).argmin(-1)
        onehot = torch.nn.functional.one_hot(lab, k).to(points.dtype)  # (starts, M, k)
        cnt = onehot.sum(1)
        new = torch.einsum("smk,smi->ski", onehot, X) / (cnt.unsqueeze(-1) + EPS)
        C = torch.where(cnt.unsqueeze(-1) > 0, new, C)
    return C


def candidate_keypoints(template: torch.Tensor, num_parts: int, directions: int = 48, starts: int = 48,
                        generator: torch.Generator | None = None) -> torch.Tensor:
    """Candidate keypoint sets ``(C, P, 3)`` for ``template (M, 3)``: for ``P = 2``, the centroids of
    the two sides of planes through the template centroid over ``directions`` hemisphere directions;
    for any ``P``, k-means solutions from ``starts`` random seedings."""
    cands = []
    if num_parts == 2:
        u = fibonacci_hemisphere(directions, template.dtype).to(template.device)
        c = template.mean(0)
        side = ((template - c) @ u.T) > 0  # (M, D)
        pos = side.T.to(template.dtype)  # (D, M)
        neg = 1.0 - pos
        kp = torch.stack([neg @ template / (neg.sum(1, keepdim=True) + EPS),
                          pos @ template / (pos.sum(1, keepdim=True) + EPS)], 1)
        ok = (pos.sum(1) >= 0.1 * len(template)) & (neg.sum(1) >= 0.1 * len(template))
        cands.append(kp[ok])
    if starts > 0:
        cands.append(kmeans(template, num_parts, starts, generator=generator))
    return torch.cat(cands, 0)


def score_keypoints(clouds: torch.Tensor, candidates: torch.Tensor, pairs: int = 32, iters: int = 8,
                    clip: float = 0.01, generator: torch.Generator | None = None, chunk: int = 16) -> torch.Tensor:
    """Rigidity score of every candidate (lower is better): ``clouds (B, n, 3)`` canonical clouds,
    ``candidates (C, P, 3)`` -> ``(C,)`` mean :func:`part_rigidity_residual` over ``pairs`` random
    ordered pairs of different clouds (the same pairs for every candidate)."""
    B = clouds.shape[0]
    if B < 2:
        raise ValueError("scoring a part split needs at least two clouds")
    a, b = random_pairs(B, pairs, generator)
    A, Bc = clouds[a.to(clouds.device)], clouds[b.to(clouds.device)]
    C, P, _ = candidates.shape
    scores = []
    for k in range(0, C, chunk):
        K = candidates[k:k + chunk]  # (c, P, 3)
        c = K.shape[0]
        Kc = K.repeat_interleave(pairs, 0)
        la = nearest_keypoint(A.repeat(c, 1, 1), Kc)
        lb = nearest_keypoint(Bc.repeat(c, 1, 1), Kc)
        r = part_rigidity_residual(A.repeat(c, 1, 1), Bc.repeat(c, 1, 1), la, lb, P, iters, clip)
        scores.append(r.reshape(c, pairs).mean(1))
    return torch.cat(scores)


def base_first_order(K: torch.Tensor) -> list[int]:
    """The slot order with the base first: the keypoint with the smallest summed distance to the others (the hub of a
    star-shaped tree), then the others in their order; ties (two parts) keep the order. ``K (P, 3)``."""
    d = torch.cdist(K, K).sum(1)
    base = int(torch.argmin(d - 1e-6 * (torch.arange(len(K), device=K.device) == 0).to(K.dtype)))
    return [base] + [p for p in range(len(K)) if p != base]


def order_base_first(K: torch.Tensor) -> torch.Tensor:
    """Put the base (slot 0) first (:func:`base_first_order`): ``K (P, 3)`` -> ``(P, 3)``."""
    return K[base_first_order(K)]


def initial_split(clouds: torch.Tensor, template: torch.Tensor, num_parts: int, seed: int = 0,
                  pairs: int = 32, directions: int = 48, starts: int = 48) -> tuple[torch.Tensor, torch.Tensor]:
    """The most rigid starting split: ``clouds (B, n, 3)`` canonical training clouds, ``template
    (M, 3)`` (the candidates' source, see :func:`candidate_keypoints` for ``directions`` and
    ``starts``) -> (keypoints ``(P, 3)`` with the base first, scores of all candidates ``(C,)``).

    Raises ``ValueError`` for fewer than two clouds or ``num_parts < 2``.
    """
    if num_parts < 2:
        raise ValueError(f"a part split needs at least two parts, got {num_parts}")
    g = torch.Generator().manual_seed(seed)
    cands = candidate_keypoints(template, num_parts, directions, starts, generator=g)
    scores = score_keypoints(clouds, cands, pairs=pairs, generator=g)
    return order_base_first(cands[int(torch.argmin(scores))]), scores


def medoid(clouds: torch.Tensor, keep: float = 0.7) -> int:
    """Index of the medoid of ``clouds (B, n, 3)`` under the symmetric trimmed one-sided Chamfer
    distance (the ``keep`` fraction of smallest nearest-neighbour distances, which tolerates partial
    views): the cloud with the smallest mean distance to the others."""
    B, n, _ = clouds.shape
    D = torch.zeros(B, B, dtype=clouds.dtype)
    for a in range(B):
        D[a] = trimmed_one_sided_chamfer(clouds[a:a + 1].expand(B, n, 3), clouds, keep)
    D = D + D.T
    return int(D.sum(1).argmin())


def part_centroids(points: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Centroids ``(P, 3)`` of ``points (M, 3)`` grouped by nearest keypoint ``K (P, 3)``; a keypoint
    with no points keeps its place."""
    lab = nearest_keypoint(points, K)
    out = K.clone()
    for p in range(len(K)):
        if (lab == p).any():
            out[p] = points[lab == p].mean(0)
    return out


def boundary_joint(template: torch.Tensor, K: torch.Tensor, parent: int, child: int, top: float = 0.1,
                   labels: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Initial pivot and axis of the joint between two parts of ``template (M, 3)`` split by nearest
    keypoint ``K (P, 3)`` (or by ``labels (M,)`` int64 when given): the ``top`` fraction of the two parts' points
    closest to the plane bisecting their keypoints; pivot = their mean, axis = their principal direction.
    -> ``pivot (3,), axis (3,)``."""
    lab = nearest_keypoint(template, K) if labels is None else labels
    pts = template[(lab == parent) | (lab == child)]
    n = K[child] - K[parent]
    n = n / (n.norm() + EPS)
    mid = 0.5 * (K[child] + K[parent])
    dist = ((pts - mid) @ n).abs()
    k = max(3, int(top * len(pts)))
    sel = pts[dist.topk(min(k, len(pts)), largest=False).indices]
    pivot = sel.mean(0)
    cov = (sel - pivot).T @ (sel - pivot)
    axis = torch.linalg.eigh(cov).eigenvectors[:, -1]
    return pivot, axis


def estimate_axes(clouds: torch.Tensor, K: torch.Tensor, joint_types, joint_parts, pairs: int = 128,
                  min_fraction: float = 0.1, generator: torch.Generator | None = None,
                  labels: torch.Tensor | None = None) -> list[torch.Tensor | None]:
    """Joint axes from the articulation seen across canonical ``clouds (B, n, 3)`` split by nearest
    keypoint ``K (P, 3)`` (or by ``labels (B, n)`` int64 when given): for random pairs of clouds both parts of a joint
    are registered (:func:`register_parts`) and the child's motion relative to its parent, ``M = T_child
    T_parent^-1``, goes to :func:`axis_from_motions` (pairs where a part has under ``min_fraction``
    of the points in either cloud are skipped). Returns per joint an axis ``(3,)`` or ``None``.
    """
    B, n, _ = clouds.shape
    if B < 2:
        raise ValueError("estimating joint axes needs at least two clouds")
    a, b = random_pairs(B, pairs, generator)
    A, Bc = clouds[a], clouds[b]
    P = K.shape[0]
    if labels is None:
        la, lb = nearest_keypoint(A, K.expand(pairs, P, 3)), nearest_keypoint(Bc, K.expand(pairs, P, 3))
    else:
        la, lb = labels[a], labels[b]
    _, R, t = register_parts(A, Bc, la, lb, P)
    out = []
    for (pa, ch), jt in zip(joint_parts, joint_types):
        ok = torch.ones(pairs, dtype=torch.bool)
        for lab in (la, lb):
            for p in (pa, ch):
                ok &= (lab == p).float().mean(1) >= min_fraction
        Rm = R[:, ch] @ R[:, pa].transpose(1, 2)
        tm = t[:, ch] - (Rm @ t[:, pa].unsqueeze(-1)).squeeze(-1)
        out.append(axis_from_motions(Rm[ok], tm[ok], int(jt)))
    return out


def axis_from_turns(clouds: torch.Tensor, labels: torch.Tensor, child: int, min_points: int = 16,
                    directions: int = 4000) -> torch.Tensor | None:
    """The revolute axis ``(3,)`` about which a part's principal axes turn across clouds held in one frame (an
    addition to the paper; ``TrainConfig.axis_init = "turn"``).

    Under a turn about the unit axis ``d`` every direction ``e`` rigid with the part keeps ``(e . d)^2``; so per cloud
    the child's principal axes ``e_k`` (eigenvectors of its points' covariance, sign-free through the square) are taken,
    and ``d`` is the direction of a hemisphere grid of ``directions`` that minimises the variance over clouds of
    ``(e_k . d)^2``, summed over ``k``, each axis weighted by how well its eigenvalue is separated from the others
    (``min(gap to the nearest eigenvalue, largest) / largest``: the roll of a thin bar about its own length, or the
    in-plane axes of a round disc, are not seen, and weigh nothing). Registration of the part across clouds
    (:func:`estimate_axes`) reads such unseen rolls as motion: on eyeglasses' temples (thin bars) it gives axes 84-90
    deg off with the true split, where this gives 2-4 deg (``results/canonical_ladder/axis_init/`` (at 9a79e15)).

    Args:
        clouds: ``(B, n, 3)`` clouds in one frame (canonical, normalised units), the parent part held still in it.
        labels: ``(B, n)`` int64 part labels. child: the joint's child part.
        min_points: clouds where the child has fewer points are skipped.

    Returns:
        The unit axis ``(3,)`` (sign arbitrary), or None when fewer than three clouds show the child.
    """
    E, W = [], []
    for x, lab in zip(clouds, labels):
        q = x[lab == child]
        if len(q) < min_points:
            continue
        q = q - q.mean(0)
        ev, U = torch.linalg.eigh(q.T @ q / len(q))  # ascending
        top = ev[2].clamp_min(EPS)
        gap = torch.stack([torch.minimum(min(abs(ev[k] - ev[i]) for i in range(3) if i != k), ev[2])
                           for k in range(3)]) / top
        E.append(U.T)
        W.append(gap)
    if len(E) < 3:
        return None
    E, W = torch.stack(E), torch.stack(W)  # (C, 3, 3) rows e_k; (C, 3)
    D = fibonacci_hemisphere(directions, clouds.dtype).to(clouds.device)
    proj = torch.einsum("cki,di->cdk", E, D) ** 2  # (C, dirs, 3)
    Wc = W[:, None]
    mean = (Wc * proj).sum(0) / W.sum(0).clamp_min(EPS)
    cost = (Wc * (proj - mean) ** 2).sum(0).sum(-1)  # (dirs,)
    return D[cost.argmin()]


def estimate_axes_turn(clouds: torch.Tensor, labels: torch.Tensor, joint_types, joint_parts,
                       fallback: list[torch.Tensor | None]) -> list[torch.Tensor | None]:
    """Per joint: :func:`axis_from_turns` of its child for a revolute joint; ``fallback[j]`` (e.g.
    :func:`estimate_axes`) for a prismatic joint or where too few clouds show the child. ``clouds (B, n, 3)``,
    ``labels (B, n)`` int64."""
    out = []
    for j, ((_, child), jt) in enumerate(zip(joint_parts, joint_types)):
        axis = axis_from_turns(clouds, labels, int(child)) if int(jt) == 0 else None
        out.append(fallback[j] if axis is None else axis)
    return out


def register_template_parts(template: torch.Tensor, labels: torch.Tensor, clouds: torch.Tensor, num_parts: int,
                            iters: int = 6, clip: float = 0.01, R: torch.Tensor | None = None,
                            t: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Register each part of ``template (M, 3)`` (split by ``labels (M,)`` int64) rigidly onto each of ``clouds (B, n,
    3)``: ``iters`` point-to-point ICP steps from ``R (B P, 3, 3), t (B P, 3)`` (row ``b P + p``: part ``p`` onto cloud
    ``b``; default the identity), matched to *any* point of the cloud, matches farther than ``2 sqrt(clip)`` ignored;
    a part with under three matches keeps its motion. Returns ``(R, t, d2)`` with ``d2 (B, P, M)`` the squared distance
    of every template point, moved by each part's motion, to its nearest cloud point."""
    M, B, P = template.shape[0], clouds.shape[0], num_parts
    dt, dev = template.dtype, template.device
    R = torch.eye(3, dtype=dt, device=dev).expand(B * P, 3, 3).clone() if R is None else R
    t = torch.zeros(B * P, 3, dtype=dt, device=dev) if t is None else t
    target = clouds.repeat_interleave(P, 0)  # (BP, n, 3): row b*P + p is cloud b for part p
    slot = torch.arange(P, device=dev).repeat(B)[:, None]  # (BP, 1)
    src = template.expand(B * P, M, 3)
    for it in range(iters + 1):
        dmin, j = pairwise_sq_dist(src @ R.transpose(1, 2) + t[:, None], target).min(-1)
        if it == iters:
            break
        w = ((labels[None] == slot) & (dmin < 4 * clip)).to(dt)
        Rn, tn = kabsch(src, target.gather(1, j.unsqueeze(-1).expand(-1, -1, 3)), w)
        ok = w.sum(1) >= 3
        R = torch.where(ok[:, None, None], Rn, R)
        t = torch.where(ok[:, None], tn, t)
    return R, t, dmin.reshape(B, P, M)


def _posed(template: torch.Tensor, labels: torch.Tensor, R: torch.Tensor, t: torch.Tensor, B: int,
           P: int) -> torch.Tensor:
    """``template (M, 3)``, each point moved by its part's motion ``R (B P, 3, 3), t (B P, 3)`` -> ``(B, M, 3)``."""
    M = template.shape[0]
    moved = (template.expand(B * P, M, 3) @ R.transpose(1, 2) + t[:, None]).reshape(B, P, M, 3)
    return moved.gather(1, labels.view(1, 1, M, 1).expand(B, 1, M, 3)).squeeze(1)


def label_clouds(template: torch.Tensor, labels: torch.Tensor, clouds: torch.Tensor, num_parts: int,
                 R: torch.Tensor | None = None, t: torch.Tensor | None = None, iters: int = 6, chunk: int = 64
                 ) -> torch.Tensor:
    """Label every point of ``clouds (B, n, 3)`` with the part of its nearest point of the template posed for that
    cloud, each part of ``template (M, 3)`` (split by ``labels (M,)``) at its motion (:func:`register_template_parts`
    from ``R (B P, 3, 3), t (B P, 3)`` when given, else ``iters`` ICP steps from the identity), ``chunk`` clouds at a
    time -> ``(B, n)`` int64."""
    out = []
    P = num_parts
    for k in range(0, clouds.shape[0], chunk):
        C = clouds[k:k + chunk]
        if R is None:
            Rc, tc, _ = register_template_parts(template, labels, C, P, iters)
        else:
            Rc, tc = R[k * P:(k + len(C)) * P], t[k * P:(k + len(C)) * P]
        posed = _posed(template, labels, Rc, tc, len(C), P)  # each point at its part's motion
        out.append(labels[pairwise_sq_dist(C, posed).argmin(-1)])
    return torch.cat(out)


def fit_template_parts(template: torch.Tensor, clouds: torch.Tensor, labels: torch.Tensor, num_parts: int,
                       rounds: int = 8, iters: int = 6, clip: float = 0.01) -> tuple[torch.Tensor, torch.Tensor]:
    """Split a template by fitting it, part by part, to every canonical cloud (an addition to the paper).

    Alternates two steps from the template's ``labels (M,)``: (1) each part of ``template (M, 3)`` is registered
    rigidly onto each cloud of ``clouds (B, n, 3)`` (:func:`register_template_parts`, ``iters`` ICP steps continuing
    from the previous round); (2) each template point goes to the part whose motions place it nearest the clouds, its
    squared distance to the nearest cloud point clipped at ``clip`` and averaged over the clouds. A part of the
    template is thus whatever moves as one rigid body across the clouds; where the Voronoi cells of
    :func:`initial_split`'s keypoints cannot draw a part (an eyeglasses temple folded along the front), these labels
    can. A local method: :func:`choose_split` runs it from many starts.

    Args:
        template: ``(M, 3)``, one canonical cloud (normalised units). clouds: ``(B, n, 3)`` in the same frame.
        labels: ``(M,)`` int64 starting labels in ``[0, num_parts)``. rounds, iters, clip: as above.

    Returns:
        ``(labels (M,) int64, cloud_labels (B, n) int64)``: the template's split, and each cloud point labelled by the
        part of its nearest point of the posed template (:func:`label_clouds`, each part at the motion of the last
        round, i.e. fitted to the labels before the last relabelling when ``rounds`` ran out).
    """
    R = t = None
    labels = labels.clone()
    for _ in range(rounds):
        R, t, d2 = register_template_parts(template, labels, clouds, num_parts, iters, clip, R, t)
        new = d2.clamp(max=clip).mean(0).argmin(0)  # (M,)
        if torch.equal(new, labels):
            break
        labels = new
    if R is None:  # no round: the parts at their motions for the starting labels
        R, t, _ = register_template_parts(template, labels, clouds, num_parts, iters, clip)
    return labels, label_clouds(template, labels, clouds, num_parts, R, t, chunk=clouds.shape[0])


#: ``TrainConfig.split_overseg``'s largest cluster count: the groupings of 7 clusters into 3 parts are 301 fits.
MAX_OVERSEG_CLUSTERS = 7


def set_partitions(items: int, blocks: int) -> list[tuple[int, ...]]:
    """Every way to put ``items`` labelled items into exactly ``blocks`` unlabelled non-empty groups, each as a tuple of
    group indices per item numbered by first appearance (restricted growth strings): the Stirling number of the second
    kind ``S(items, blocks)`` of them (``S(6, 3) = 90``). Empty where ``blocks`` is not in ``[1, items]``."""
    out: list[tuple[int, ...]] = []

    def grow(prefix: list[int], used: int) -> None:
        if len(prefix) == items:
            if used == blocks:
                out.append(tuple(prefix))
            return
        if blocks - used > items - len(prefix):  # too few items left to open the missing groups
            return
        for b in range(min(used + 1, blocks)):
            grow(prefix + [b], max(used, b + 1))

    if 1 <= blocks <= items:
        grow([], 0)
    return out


def overseg_starts(template: torch.Tensor, num_parts: int, clusters: int, seed: int = 0) -> list[torch.Tensor]:
    """Starting splits of ``template (M, 3)`` from an over-segmentation (``TrainConfig.split_overseg``, an addition to
    the paper): :func:`kmeans` into ``clusters`` clusters (one k-means++ seeding from ``seed``, its own generator), then
    every grouping of the clusters into ``num_parts`` parts (:func:`set_partitions`) -> a list of ``S(clusters,
    num_parts)`` label tensors ``(M,)`` int64. Random keypoint starts rarely draw a part made of the template's far
    ends (an eyeglasses temple on either side of the front); groups of clusters can (results/canonical_ladder/
    stage2_parts/scale/ at 9a79e15).

    Raises:
        ValueError: ``clusters`` outside ``[num_parts, MAX_OVERSEG_CLUSTERS]`` or above the template's points."""
    if not num_parts <= clusters <= min(MAX_OVERSEG_CLUSTERS, template.shape[0]):
        raise ValueError(f"an over-segmentation into {clusters} clusters needs num_parts ({num_parts}) <= clusters <= "
                         f"{min(MAX_OVERSEG_CLUSTERS, template.shape[0])}")
    centres = kmeans(template, clusters, 1, generator=torch.Generator().manual_seed(seed))[0]
    cluster = nearest_keypoint(template, centres)
    return [torch.tensor(g, dtype=torch.long, device=template.device)[cluster]
            for g in set_partitions(clusters, num_parts)]


#: :func:`choose_split`: scores within this of the least are tied and the earliest such candidate wins. Clouds that
#: never move make every split rigid up to float32 noise (scores of a few 1e-9, whose order differs between CPUs);
#: real splits score about 5e-3 with differences of 1e-7 and more (a run's ``split_init.json``).
SPLIT_TIE = 1e-8


def choose_split(clouds: torch.Tensor, template: torch.Tensor, K: torch.Tensor, starts: int = 24, pairs: int = 128,
                 seed: int = 0, rounds: int = 8, keypoint_split: bool = True, overseg: int = 0) -> dict:
    """The most rigid of the keypoint split and template splits found by fitting (``TrainConfig.split_init="fit"``).

    Candidates: the split by nearest keypoint ``K (P, 3)`` (:func:`initial_split`'s choice) and
    :func:`fit_template_parts` started from it and from ``starts`` random keypoint sets (``P`` template points drawn at
    random). Each is scored as :func:`initial_split` scores keypoints, by :func:`part_rigidity_residual` over ``pairs``
    random pairs of the ``clouds (B, n, 3)`` (the same pairs for every candidate), the clouds labelled by the
    candidate; the lowest wins (scores within :data:`SPLIT_TIE` of it tie, and the earliest of those wins). With
    ``keypoint_split=False`` (``TrainConfig.split_init="fitted"``) the keypoint split is scored but cannot win: the
    lowest of the fits does (the keypoint split still wins when no fit keeps ``P`` parts).
    With ``overseg`` (``TrainConfig.split_overseg``, 0: off) the fits from :func:`overseg_starts` (the template in
    ``overseg`` k-means clusters, every grouping into ``P`` parts) are candidates too, after the others (which stay as
    they were). With the frame given (``bench/diagnostics/split_init_diagnosis.py``, three seeds, no
    labels used), on eyeglasses the chosen split's mean IoU with the true parts is about twice the keypoint split's
    (about 0.7 against 0.3, on complete clouds and on the paper's partial views); the figures per seed and the laptop's
    are in ``results/canonical_ladder/split_init/`` (at 9a79e15).

    Args:
        clouds: ``(B, n, 3)`` canonical training clouds (``B >= 2``). template: ``(M, 3)`` one of them (stage 2's
            ``Y_base``). K: ``(P, 3)`` the keypoint split's keypoints. starts, pairs, seed, rounds,
            keypoint_split, overseg: as above.

    Returns:
        dict with ``template_labels (M,)`` and ``cloud_labels (B, n)`` (int64) of the winner, ``source`` ("keypoints"
        or "fit"), ``scores`` (keypoint split first, then the fits, floats) and ``chosen`` (its index).

    Raises:
        ValueError: fewer than two clouds; ``overseg`` not 0 and outside :func:`overseg_starts`'s range.
    """
    B, P = clouds.shape[0], K.shape[0]
    if B < 2:
        raise ValueError("choosing a part split needs at least two clouds")
    g = torch.Generator().manual_seed(seed)
    a, b = random_pairs(B, pairs, g)

    def score(cl: torch.Tensor) -> float:
        return float(part_rigidity_residual(clouds[a], clouds[b], cl[a], cl[b], P).mean())

    kp_cloud = nearest_keypoint(clouds, K.expand(B, P, 3))
    cands = [(nearest_keypoint(template, K), kp_cloud, "keypoints")]
    for k in range(starts + 1):
        Kr = K if k == 0 else template[torch.randperm(len(template), generator=g)[:P]]
        lab, cl = fit_template_parts(template, clouds, nearest_keypoint(template, Kr), P, rounds=rounds)
        if len(torch.unique(lab)) == P:  # a fit that emptied a part is not a split into P parts
            cands.append((lab, cl, "fit"))
    for start in overseg_starts(template, P, overseg, seed) if overseg else []:
        lab, cl = fit_template_parts(template, clouds, start, P, rounds=rounds)
        if len(torch.unique(lab)) == P:
            cands.append((lab, cl, "fit"))
    scores = [score(cl) for _, cl, _ in cands]
    eligible = range(1 if len(cands) > 1 and not keypoint_split else 0, len(cands))
    least = min(scores[k] for k in eligible)
    best = next(k for k in eligible if scores[k] <= least + SPLIT_TIE)  # ties: the earliest candidate
    return {"template_labels": cands[best][0], "cloud_labels": cands[best][1], "source": cands[best][2],
            "scores": scores, "chosen": best}


def base_first_labels(template: torch.Tensor, labels: torch.Tensor, num_parts: int
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """Renumber a template split so that the base comes first: ``template (M, 3)``, ``labels (M,)`` int64 -> (``perm
    (P,)`` int64 with ``new = perm[old]``, ``centroids (P, 3)`` in the new order). A part with no point gets the
    template's centroid.

    With three or more parts the base is the part with the most template points (ties: the hub of
    :func:`base_first_order`), the others keep their order; with two, the order is kept (either part can be the root
    of one joint). Not the hub of the centroids, as :func:`base_first_order` orders keypoints: children folded onto
    their parent lie together, so their centroids are nearer each other than the parent's (an eyeglasses template
    with its temples shut put a temple first in five of six training runs, ``docs/canonical_ladder.md``),
    while the body a star-shaped tree's children hang from is the largest part of both benchmark categories
    with more than two parts (the eyeglasses' front: about 0.57 of the points; the basket's body)."""
    C = torch.stack([template[labels == p].mean(0) if bool((labels == p).any()) else template.mean(0)
                     for p in range(num_parts)])
    order = list(range(num_parts))
    if num_parts >= 3:
        size = torch.bincount(labels[labels >= 0], minlength=num_parts)[:num_parts].to(C.dtype)
        hub = torch.cdist(C, C).sum(1)
        base = int(torch.argmin(-size + 1e-9 * hub / hub.max().clamp_min(1e-12)))
        order = [base] + [p for p in range(num_parts) if p != base]
    perm = torch.empty(num_parts, dtype=torch.long, device=labels.device)
    perm[torch.tensor(order, device=labels.device)] = torch.arange(num_parts, device=labels.device)
    return perm, C[order]
