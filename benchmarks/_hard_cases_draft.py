import sys, time, warnings; sys.path.insert(0,'/work/main')
import numpy as np
import astroalign_nd as A
from astroalign_nd.simulate import simulate_pair
from astroalign_nd.transforms import AffineTransform, SimilarityTransform
def frame_err(t, truth, shape):
    ny,nx=shape; yy,xx=np.mgrid[0:ny:16,0:nx:16]
    q = truth.inverse(xx.ravel().astype(float), yy.ravel().astype(float))
    # only target pixels whose preimage lies in the source frame matter; keep all (whole target frame)
    a=np.array(t(*q)); return np.hypot(a[0]-xx.ravel(), a[1]-yy.ravel()).max()
def shear_matrix():
    # rotation 20 deg + 3% shear, centred
    c,s=np.cos(0.35),np.sin(0.35); lin=np.array([[c,-s],[s,c]])@np.array([[1.0,0.03],[0,1.0]])
    m=np.eye(3); m[:2,:2]=lin; ctr=np.array([255.5,255.5]); m[:2,2]=ctr-lin@ctr+[5.3,-2.1]; return m
F=dict(flux_range=(1e3,3e5))
CASES = {
 'scale 1:3': dict(shape=(768,768), n_stars=600, scale=1/3, rotation=40.0, fwhm=6.0, target_fwhm=2.0, **F),
 'scale 3:1': dict(shape=(512,512), n_stars=400, scale=3.0, rotation=-20.0, fwhm=2.0, target_fwhm=5.0, **F),
 'mirrored': dict(n_stars=300, rotation=75.0, mirror=True, **F),
 'meridian flip 180': dict(n_stars=300, rotation=180.0, translation=(3.2,-4.7), **F),
 'overlap 25%': dict(n_stars=600, rotation=5.0, translation=(256.0,256.0), **F),
 'half missing + transients': dict(n_stars=300, rotation=30.0, missing_fraction=0.5, n_transients=150, **F),
 'hot pixels + cosmics': dict(n_stars=300, rotation=30.0, n_hot_pixels=500, n_cosmic_rays=200, **F),
 'crowded 30k/1024': dict(shape=(1024,1024), n_stars=30000, rotation=30.0, flux_range=(300,3e5), noise='gaussian'),
 'fwhm 2 vs 9': dict(n_stars=300, rotation=30.0, fwhm=2.0, target_fwhm=9.0, **F),
 'gradient': dict(n_stars=300, rotation=30.0, gradient=3.0, **F),
 'saturated': dict(n_stars=300, rotation=30.0, saturation=5000.0, **F),
 'low snr': dict(n_stars=300, rotation=30.0, flux_range=(100,3000), background=1000.0),
 'rectangular': dict(shape=(300,900), n_stars=300, rotation=8.0, **F),
 'affine shear (affine)': dict(n_stars=300, transform=shear_matrix(), **F),
}
only = sys.argv[1:] 
import astroalign as aa
for name, kw in CASES.items():
    if only and not any(o in name for o in only): continue
    kw=dict(kw); kw.setdefault('seed', 7)
    p = simulate_pair(**kw)
    opts = dict(transform_type='affine') if 'affine' in name else {}
    t0=time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter('always')
            t,_ = A.find_transform(p.source, p.target, **opts)
        e = frame_err(t, p.transform, p.target.shape); q=t.meta['quality']; info=f"n={q['n_matches']} rms={q['rms']:.3f} lfa={q['log10_false_alarm']:.0f} {[str(x.message)[:40] for x in w]}"
    except Exception as ex:
        e=np.nan; info=str(ex)[:150]
    dt=time.perf_counter()-t0
    t0=time.perf_counter()
    try:
        T,_=aa.find_transform(p.source,p.target); ea=frame_err(AffineTransform.from_matrix(T.params), p.transform, p.target.shape)
    except Exception as ex: ea=np.nan
    da=time.perf_counter()-t0
    print(f"{name:28s} err {e:8.3f}  aa {ea:8.3f}  t {dt:.2f}/{da:.2f}  {info}", flush=True)
