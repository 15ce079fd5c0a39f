// The lattice planner's search in native code, called from Python through ctypes
// (quadrivio_navigation/lattice.py, LatticeParams.native): anytime repairing A* (ARA*,
// Likhachev, Gordon and Thrun, NIPS 2003) over motion primitives whose swept cells are
// precomputed, with the lazy non-holonomic heuristic and the analytic Reeds-Shepp
// expansions to the goal. Python prepares everything that is done once per plan (the
// cost grid, the primitives' cells, the 2-D heuristic, the start's connectors) and turns
// the chain of states this returns into poses; this runs the loop that costs about
// 100 us an expansion in Python and a microsecond here.
//
// It is the Python search (LatticePlanner._search_python) step for step: the same open
// list ordered by (f, push counter), the same stale-entry and lazy-heuristic rules, the
// same analytic expansion every shot_every-th expansion near the goal, the same
// footprint templates for it. One pass of weighted A* gives the same path and the same
// expansions as Python's (test_lattice_native.py); between passes the re-opened states
// are queued by state number, where Python queues them in dict and set order, so later
// passes may break ties otherwise.

#include "quadrivio_navigation/curves_core.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <queue>
#include <unordered_map>
#include <unordered_set>
#include <vector>

using namespace qv_curves;

namespace
{
const uint8_t kLethal = 255;
const double kInf = std::numeric_limits<double>::infinity();
const int64_t kGoal = -1;  // the exact goal
const int kShot = -2, kSnap = -1, kRoot = -4;

struct Lattice
{
    // padded cost grid: LETHAL around the map, so swept cells never index outside
    std::vector<uint8_t> flat;
    int hp, wp, pad, h, w, n;
    double res;
    // primitives per start heading
    std::vector<std::vector<int64_t>> dflat;   // end cell - start cell (unpadded flat index)
    std::vector<std::vector<int>> kEnd;        // end heading
    std::vector<std::vector<double>> base;     // length x cost multiplier
    std::vector<std::vector<int64_t>> starts;  // first swept cell of each primitive in offsets
    std::vector<std::vector<int64_t>> offsets; // swept cells, padded flat offsets from the start cell
    // footprint templates of the analytic expansions (PoseChecker): bins x sub x sub, m cells each
    std::vector<int32_t> tRows, tCols;
    int tBins, tSub, tM;
    double r, rc, costWeight;
    bool reverse;
    std::vector<double> overhead;

    // the last plan's results
    std::vector<int64_t> chainStates;  // the chain's states, the first one's parent is the root
    std::vector<int> chainPrims;       // primitive from the previous state (-1 snap, -2 shot)
    std::vector<double> chainG;        // g of each state
    std::vector<double> solutions;     // (seconds, cost, bound, expansions) per improvement
    std::vector<int32_t> expanded;     // (row, col) of every expanded state
    std::vector<double> shot;          // the goal shot's segments: (kind as 'L' 'S' 'R', length m)

    rs::Word word(double x0, double y0, double th0, double x1, double y1, double th1) const
    {
        if (reverse)
        {
            double dx = x1 - x0, dy = y1 - y0, c = std::cos(th0), s = std::sin(th0);
            return rs::cheapest((c * dx + s * dy) / r, (-s * dx + c * dy) / r, th1 - th0, rc);
        }
        return dubins::shortest((x1 - x0) / r, (y1 - y0) / r, th0, th1);
    }

    // curves.path_cost of the word: its length in metres, reverse parts counted rc times
    double wordCost(const rs::Word &wd) const
    {
        double c = 0.0;
        for (int i = 0; i < wd.n; ++i)
        {
            if (std::fabs(wd.len[i]) <= 1e-12)
                continue;
            double v = wd.len[i] * r;
            c += v > 0 ? v : -rc * v;
        }
        return c;
    }

    // LatticePlanner._shot_cost: the word sampled every half cell (curves.sample), each
    // pose's grown footprint template; -1 when it collides or leaves the padded grid.
    double shotCost(double x, double y, double th, const rs::Word &wd) const
    {
        double step = 0.5 * res;
        int worst = 0;
        auto check = [&](double px, double py, double pth) -> bool {
            double gx = px / res, gy = py / res;
            double cx = std::floor(gx), cy = std::floor(gy);
            int j = std::min(tSub - 1, (int)((gx - cx) * tSub));
            int i = std::min(tSub - 1, (int)((gy - cy) * tSub));
            int b = (int)std::nearbyint(pth / kTwoPi * tBins) % tBins;
            if (b < 0)
                b += tBins;
            size_t t = ((size_t)(b * tSub + i) * tSub + j) * tM;
            int64_t ry = (int64_t)cy + pad, rx = (int64_t)cx + pad;
            for (int k = 0; k < tM; ++k)
            {
                int64_t row = tRows[t + k] + ry, col = tCols[t + k] + rx;
                if (row < 0 || col < 0 || row >= hp || col >= wp)
                    return false;
                int v = flat[(size_t)(row * wp + col)];
                if (v > worst)
                {
                    if (v == kLethal)  // Python takes the maximum first: the same verdict
                        return false;
                    worst = v;
                }
            }
            return true;
        };
        if (!check(x, y, th))
            return -1.0;
        double px = x, py = y, pth = th;
        for (int s = 0; s < wd.n; ++s)
        {
            if (std::fabs(wd.len[s]) <= 1e-12)
                continue;
            double length = wd.len[s] * r;
            int m = std::max(1, (int)std::ceil(std::fabs(length) / step));
            double sx = px, sy = py, sth = pth;
            for (int i = 1; i <= m; ++i)
            {
                px = sx;
                py = sy;
                pth = sth;
                advance(px, py, pth, wd.kind[s], length * i / m, r);
                if (!check(px, py, pth))
                    return -1.0;
            }
        }
        if (worst == kLethal)
            return -1.0;
        return wordCost(wd) * (1.0 + costWeight * worst / 254.0);
    }
};

struct Entry
{
    double f;
    int64_t counter, s;
    bool operator>(const Entry &o) const
    {
        return f > o.f || (f == o.f && counter > o.counter);
    }
};

}  // namespace

extern "C" {

// The planner of one cost grid and primitive set (see LatticePlanner.__init__ for each
// array). Returns a handle, or null on bad arguments.
void *qv_lattice_create(const uint8_t *padded, int hp, int wp, int pad, int h, int w, double res, int n,
                        const int *counts, const int64_t *dflat, const int *k_end, const double *base,
                        const int *cell_counts, const int64_t *offsets, const int32_t *t_rows,
                        const int32_t *t_cols, int t_bins, int t_sub, int t_m, double turning_radius, int reverse,
                        double reverse_cost, double cost_weight, const double *overhead, int obins)
{
    if (!padded || hp < 1 || wp < 1 || h < 1 || w < 1 || n < 1 || !(res > 0) || !(turning_radius > 0) || t_m < 1 ||
        obins < 1)
        return nullptr;
    auto *L = new Lattice();
    L->flat.assign(padded, padded + (size_t)hp * wp);
    L->hp = hp;
    L->wp = wp;
    L->pad = pad;
    L->h = h;
    L->w = w;
    L->n = n;
    L->res = res;
    size_t p = 0, c = 0;
    L->dflat.resize(n);
    L->kEnd.resize(n);
    L->base.resize(n);
    L->starts.resize(n);
    L->offsets.resize(n);
    for (int k = 0; k < n; ++k)
    {
        int64_t at = 0;
        for (int j = 0; j < counts[k]; ++j, ++p)
        {
            L->dflat[k].push_back(dflat[p]);
            L->kEnd[k].push_back(k_end[p]);
            L->base[k].push_back(base[p]);
            L->starts[k].push_back(at);
            for (int q = 0; q < cell_counts[p]; ++q)
                L->offsets[k].push_back(offsets[c + q]);
            c += cell_counts[p];
            at += cell_counts[p];
        }
        L->starts[k].push_back(at);
    }
    size_t tn = (size_t)t_bins * t_sub * t_sub * t_m;
    L->tRows.assign(t_rows, t_rows + tn);
    L->tCols.assign(t_cols, t_cols + tn);
    L->tBins = t_bins;
    L->tSub = t_sub;
    L->tM = t_m;
    L->r = turning_radius;
    L->reverse = reverse != 0;
    L->rc = reverse_cost;
    L->costWeight = cost_weight;
    L->overhead.assign(overhead, overhead + obins);
    return L;
}

void qv_lattice_destroy(void *handle)
{
    delete static_cast<Lattice *>(handle);
}

// One plan (LatticePlanner.plan after its preparation): h2 and descent per cell of the
// unpadded grid, the goal pose and state, the cost of the goal state's snap to the exact
// goal, the initial states with their g (the start state, or the connectors' ends, in
// push order), ARA*'s parameters, the budget in seconds and `cancelled`, polled with the
// clock every 256 expansions. stats get [expansions, best cost (inf: none), its bound,
// timed out (0/1), chain length, solutions, expanded states, shot segments].
// Returns 0 with a path, 1 without.
int qv_lattice_plan(void *handle, const double *h2, const double *descent, double gx, double gy, double gth,
                    int64_t goal_state, double snap_cost, const int64_t *init_states, const double *init_g,
                    int n_init, double eps0, double eps_step, int64_t max_expansions, double budget,
                    double nh_radius, double shot_radius, int shot_every, int (*cancelled)(void), double *stats)
{
    auto *L = static_cast<Lattice *>(handle);
    using Clock = std::chrono::steady_clock;
    const auto t0 = Clock::now();
    auto elapsed = [&]() { return std::chrono::duration<double>(Clock::now() - t0).count(); };
    const int n = L->n, w = L->w, pad = L->pad, wp = L->wp;
    const double res = L->res;
    const double nhR2 = nh_radius * nh_radius, shotR2 = shot_radius * shot_radius;
    const int obins = (int)L->overhead.size();
    const double toBin = obins / kTwoPi;
    std::vector<double> thetas(n);
    for (int k = 0; k < n; ++k)
        thetas[k] = kTwoPi * k / n;

    // one record per state reached: a single hash lookup where the Python has six dicts and sets
    struct Node
    {
        double g = kInf, f = 0.0, h = 0.0;  // f: the key it is queued with while open
        int64_t parent = kRoot;
        int prim = kRoot;
        uint8_t flags = 0;
    };
    enum : uint8_t
    {
        HAS_H = 1,
        EXACT = 2,
        OPEN = 4,
        CLOSED = 8,
        INCONS = 16
    };
    std::unordered_map<int64_t, Node> nodes;
    nodes.reserve(1 << 17);
    std::vector<int64_t> incons;
    std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> open;
    int64_t counter = 0;
    double eps = eps0;
    rs::Word shotWord;
    bool haveShot = false;

    auto heur = [&](int64_t s, bool &isExact) -> double {
        int64_t cell = s / n;
        int k = (int)(s % n);
        double hv = h2[cell];
        int64_t row = cell / w, col = cell % w;
        double x = (col + 0.5) * res, y = (row + 0.5) * res;
        double d2 = (x - gx) * (x - gx) + (y - gy) * (y - gy), d = std::sqrt(d2);
        if (d2 <= nhR2)
        {
            isExact = false;
            return hv > d ? hv : d;
        }
        int b = (int)std::nearbyint((thetas[k] - descent[cell]) * toBin) % obins;
        if (b < 0)
            b += obins;
        hv += L->overhead[b];
        isExact = true;
        return hv > d ? hv : d;
    };
    auto heurExact = [&](int64_t s) -> double {
        int64_t cell = s / n;
        int k = (int)(s % n);
        int64_t row = cell / w, col = cell % w;
        double v = L->wordCost(L->word((col + 0.5) * res, (row + 0.5) * res, thetas[k], gx, gy, gth));
        double hv = h2[cell];
        return hv > v ? hv : v;
    };
    auto hval = [&](int64_t s, Node &nd) -> double {
        if (!(nd.flags & HAS_H))
        {
            bool ex;
            nd.h = heur(s, ex);
            nd.flags |= HAS_H;
            if (ex)
                nd.flags |= EXACT;
        }
        return nd.h;
    };
    auto push = [&](int64_t s, Node &nd) {
        double f = nd.g + eps * hval(s, nd);
        nd.f = f;
        nd.flags |= OPEN;
        open.push({f, ++counter, s});
    };
    Node *goalNode = nullptr;
    auto goalG = [&]() { return goalNode ? goalNode->g : kInf; };

    for (int i = 0; i < n_init; ++i)
        nodes[init_states[i]].g = init_g[i];
    for (int i = 0; i < n_init; ++i)
        push(init_states[i], nodes[init_states[i]]);

    L->chainStates.clear();
    L->chainPrims.clear();
    L->chainG.clear();
    L->solutions.clear();
    L->expanded.clear();
    L->shot.clear();
    const int64_t maxExp = max_expansions > 0 ? max_expansions : std::numeric_limits<int64_t>::max();
    int64_t expansions = 0, shotCount = 0;
    bool timedOut = false, haveBest = false;
    double bestCost = kInf, bestBound = kInf;
    const uint8_t *flat = L->flat.data();
    const double weight = L->costWeight / 254.0;

    while (true)
    {
        // ---- ImprovePath
        while (!open.empty())
        {
            const Entry top = open.top();
            Node &nd = nodes[top.s];  // references into an unordered_map stay valid on insertion
            if (!(nd.flags & OPEN) || nd.f != top.f)  // stale entry
            {
                open.pop();
                continue;
            }
            if (goalG() <= top.f)
                break;
            open.pop();
            const int64_t s = top.s;
            if (!(nd.flags & EXACT))  // lazy heuristic: evaluate it now, re-queue if it rose
            {
                nd.flags |= EXACT;
                double hx = heurExact(s);
                if (hx > nd.h)
                {
                    nd.h = hx;
                    nd.f = nd.g + eps * hx;
                    open.push({nd.f, ++counter, s});
                    continue;
                }
            }
            nd.flags = (uint8_t)((nd.flags & ~OPEN) | CLOSED);
            ++expansions;
            if ((expansions & 255) == 0)
            {
                if (elapsed() > budget || (cancelled && cancelled()))
                {
                    timedOut = true;
                    break;
                }
            }
            if (expansions >= maxExp)
            {
                timedOut = true;
                break;
            }
            int64_t cell = s / n;
            int k = (int)(s % n);
            int64_t row = cell / w, col = cell % w;
            L->expanded.push_back((int32_t)row);
            L->expanded.push_back((int32_t)col);
            const double gs = nd.g;
            if (s == goal_state && gs + snap_cost < goalG())
            {
                goalNode = &nodes[kGoal];
                goalNode->g = gs + snap_cost;
                goalNode->parent = s;
                goalNode->prim = kSnap;
                haveShot = false;
            }
            // analytic expansion to the exact goal
            double x = (col + 0.5) * res, y = (row + 0.5) * res;
            if (shotR2 > 0 && (x - gx) * (x - gx) + (y - gy) * (y - gy) <= shotR2)
            {
                ++shotCount;
                if (shotCount % shot_every == 1 || shot_every == 1)
                {
                    rs::Word wd = L->word(x, y, thetas[k], gx, gy, gth);
                    double c = L->shotCost(x, y, thetas[k], wd);
                    if (c >= 0.0 && gs + c < goalG())
                    {
                        goalNode = &nodes[kGoal];
                        goalNode->g = gs + c;
                        goalNode->parent = s;
                        goalNode->prim = kShot;
                        shotWord = wd;
                        haveShot = true;
                    }
                }
            }
            const auto &offs = L->offsets[k];
            const auto &st = L->starts[k];
            const auto &dfl = L->dflat[k];
            const auto &kend = L->kEnd[k];
            const auto &base = L->base[k];
            const int64_t at = (row + pad) * wp + (col + pad);
            const int count = (int)base.size();
            for (int j = 0; j < count; ++j)
            {
                int cmax = 0;
                const int64_t *o = offs.data() + st[j], *oe = offs.data() + st[j + 1];
                for (; o < oe; ++o)
                {
                    int v = flat[at + *o];
                    if (v > cmax)
                    {
                        cmax = v;
                        if (v == kLethal)
                            break;
                    }
                }
                if (cmax == kLethal)
                    continue;
                int64_t s2 = (cell + dfl[j]) * n + kend[j];
                double g2 = gs + base[j] * (1.0 + weight * cmax);
                Node &n2 = nodes[s2];
                if (g2 < n2.g)
                {
                    n2.g = g2;
                    n2.parent = s;
                    n2.prim = j;
                    if (n2.flags & CLOSED)
                    {
                        if (!(n2.flags & INCONS))
                        {
                            n2.flags |= INCONS;
                            incons.push_back(s2);
                        }
                    }
                    else
                        push(s2, n2);
                }
            }
        }
        // ---- a solution of this pass
        double gg = goalG();
        if (gg < kInf && (!haveBest || gg < bestCost - 1e-9))
        {
            double low = kInf;
            bool any = false;
            for (auto &e : nodes)
                if (e.second.flags & (OPEN | INCONS))
                {
                    low = std::min(low, e.second.g + hval(e.first, e.second));
                    any = true;
                }
            double bound = (any && low > 0) ? std::min(eps, gg / low) : eps;
            haveBest = true;
            bestCost = gg;
            bestBound = bound;
            // the chain now: parents change in later passes
            L->chainStates.clear();
            L->chainPrims.clear();
            L->chainG.clear();
            int64_t s = kGoal;
            while (true)
            {
                const Node &c = nodes[s];
                L->chainStates.push_back(s);
                L->chainPrims.push_back(c.prim);
                L->chainG.push_back(c.g);
                if (c.parent == kRoot)
                    break;
                s = c.parent;
            }
            std::reverse(L->chainStates.begin(), L->chainStates.end());
            std::reverse(L->chainPrims.begin(), L->chainPrims.end());
            std::reverse(L->chainG.begin(), L->chainG.end());
            L->shot.clear();
            if (goalNode->prim == kShot && haveShot)
                for (int i = 0; i < shotWord.n; ++i)
                    if (std::fabs(shotWord.len[i]) > 1e-12)
                    {
                        L->shot.push_back((double)shotWord.kind[i]);
                        L->shot.push_back(shotWord.len[i] * L->r);
                    }
            L->solutions.insert(L->solutions.end(), {elapsed(), gg, bound, (double)expansions});
        }
        if (timedOut || !haveBest || bestBound <= 1.0 + 1e-9 || eps <= 1.0 || (open.empty() && incons.empty()))
            break;
        // ---- next pass: lower eps, re-open INCONS, re-key OPEN (by state number)
        eps = std::max(1.0, eps - eps_step);
        std::vector<int64_t> keys, re;
        for (auto &e : nodes)
        {
            if (e.second.flags & OPEN)
                keys.push_back(e.first);
            else if (e.second.flags & INCONS)
                re.push_back(e.first);
            e.second.flags &= (uint8_t)~(OPEN | CLOSED | INCONS);
        }
        std::sort(keys.begin(), keys.end());
        std::sort(re.begin(), re.end());
        keys.insert(keys.end(), re.begin(), re.end());
        incons.clear();
        open = decltype(open)();
        for (int64_t s : keys)
            push(s, nodes[s]);
    }
    stats[0] = (double)expansions;
    stats[1] = haveBest ? bestCost : kInf;
    stats[2] = haveBest ? bestBound : kInf;
    stats[3] = timedOut ? 1.0 : 0.0;
    stats[4] = (double)L->chainStates.size();
    stats[5] = (double)(L->solutions.size() / 4);
    stats[6] = (double)(L->expanded.size() / 2);
    stats[7] = (double)(L->shot.size() / 2);
    return haveBest ? 0 : 1;
}

// The last plan's results, into buffers sized by its stats.
void qv_lattice_fetch(void *handle, int64_t *chain_states, int32_t *chain_prims, double *chain_g, double *solutions,
                      int32_t *expanded, double *shot)
{
    auto *L = static_cast<Lattice *>(handle);
    if (chain_states)
        std::copy(L->chainStates.begin(), L->chainStates.end(), chain_states);
    if (chain_prims)
        std::copy(L->chainPrims.begin(), L->chainPrims.end(), chain_prims);
    if (chain_g)
        std::copy(L->chainG.begin(), L->chainG.end(), chain_g);
    if (solutions)
        std::copy(L->solutions.begin(), L->solutions.end(), solutions);
    if (expanded)
        std::copy(L->expanded.begin(), L->expanded.end(), expanded);
    if (shot)
        std::copy(L->shot.begin(), L->shot.end(), shot);
}

}  // extern "C"

extern "C" {

// Shortest distances [m] from the goal cell over the 8-connected cells marked free
// (row-major h x w; a step joins two free cells, res or res * sqrt(2) long), infinity
// where unreachable: scipy's csgraph.dijkstra on the same graph, without building it
// (0.11 s of every plan on a 500 x 500 grid). Returns 1 when the goal cell is not free.
int qv_grid_dijkstra(const uint8_t *free, int h, int w, double res, int goal, double *out)
{
    const size_t cells = (size_t)h * w;
    std::fill(out, out + cells, kInf);
    if (goal < 0 || (size_t)goal >= cells || !free[goal])
        return 1;
    const double diag = std::sqrt(2.0) * res;
    const int dr[8] = {-1, -1, -1, 0, 0, 1, 1, 1}, dc[8] = {-1, 0, 1, -1, 1, -1, 0, 1};
    typedef std::pair<double, int64_t> Item;
    std::priority_queue<Item, std::vector<Item>, std::greater<Item>> heap;
    std::vector<uint8_t> done(cells, 0);
    out[goal] = 0.0;
    heap.push({0.0, goal});
    while (!heap.empty())
    {
        Item it = heap.top();
        heap.pop();
        const int64_t u = it.second;
        if (done[u])
            continue;
        done[u] = 1;
        const int r = (int)(u / w), c = (int)(u % w);
        for (int i = 0; i < 8; ++i)
        {
            const int r2 = r + dr[i], c2 = c + dc[i];
            if (r2 < 0 || c2 < 0 || r2 >= h || c2 >= w)
                continue;
            const int64_t v = (int64_t)r2 * w + c2;
            if (!free[v] || done[v])
                continue;
            const double d = it.first + ((dr[i] != 0 && dc[i] != 0) ? diag : res);
            if (d < out[v])
            {
                out[v] = d;
                heap.push({d, v});
            }
        }
    }
    return 0;
}

}  // extern "C"
